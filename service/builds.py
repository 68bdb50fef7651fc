"""Map build jobs of the service: batch builds from run files, and the embedded default map.

Orchestration only: simulation is :func:`mapping.simulate.simulate_run`, map building is
:func:`mapping.build.build_map`, the files are :mod:`mapping.runfile` / :mod:`mapping.mapfile`.

The default map ``default`` is the paper scene (``builtin_scene("paper")``) mapped with the
paper's method from a simulated run along the built-in curved path ``paper-b`` (image-source
engine, seed :data:`DEFAULT_SEED`). It is built on the service's first start in the
background and cached in the maps directory. :func:`simulate_default_run` makes the held-out
runs the demo streams (another path and another noise seed than the map's).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mapping.build import METHODS, BuildParams, RunResult, RunSource, build_map
from mapping.files import file_sha256, read_run
from mapping.path import builtin_path
from mapping.run import Run
from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from mapping.simulate import assemble_run, iter_blocks, run_meta
from mapping.simulate.ism import IsmConfig
from mapping.wallmap import WallMap
from service.jobs import Progress
from service.mapstore import MapStore

DEFAULT_SCENE = "paper"
DEFAULT_MAP_PATH = "paper-b"
DEFAULT_SEED = 20230925
#: Per-sample SNR of the simulated runs (a clean simulation is too kind to the filter).
DEFAULT_SNR_DB = 0.0


def methods() -> tuple[str, ...]:
    """Reconstruction methods ``POST /maps/build`` accepts."""
    return tuple(METHODS)


def build_to_store(maps: MapStore, map_id: str, paths: Sequence[Path], method: str,
                   progress: Progress) -> WallMap:
    """Build a map from run files and store it as ``map_id`` (the job body)."""
    sources = [RunSource(load=functools.partial(read_run, p), name=p.name,
                         sha256=file_sha256(p)) for p in paths]
    done = [0]

    def on_run(result: RunResult) -> None:
        done[0] += 1
        progress(0.95 * done[0] / len(sources), f"mapped run {result.name}")

    progress(0.0, f"mapping {len(sources)} run(s)")
    wallmap = build_map(sources, BuildParams(method=method), workers=1, progress=on_run)
    maps.put(map_id, wallmap)
    return wallmap


def simulate_default_run(path: str = DEFAULT_MAP_PATH, seed: int = DEFAULT_SEED,
                         snr_db: float | None = DEFAULT_SNR_DB, n_blocks: int | None = None,
                         progress: Progress | None = None) -> Run:
    """A simulated run of the paper scene along a built-in path (every block, or the first
    ``n_blocks``), with white noise at ``snr_db`` drawn from ``seed``."""
    config = SonarConfig()
    scene, trajectory = builtin_scene(DEFAULT_SCENE), builtin_path(path)
    total = int(math.floor(trajectory.duration_s / config.block_s))
    n = total if n_blocks is None else min(n_blocks, total)
    engine = IsmConfig(snr_db=snr_db)
    blocks = []
    for k, blk in enumerate(iter_blocks(scene, trajectory, config, n,  # type: ignore[arg-type]
                                        engine, np.random.default_rng(seed))):
        blocks.append(blk)
        if progress is not None:
            progress((k + 1) / n, f"simulated block {k + 1}/{n}")
    meta = run_meta(scene, trajectory, engine, seed, blocks)  # type: ignore[arg-type]
    return assemble_run(blocks, config, scene.to_json(), meta)


def build_default_map(maps: MapStore, map_id: str, progress: Progress) -> WallMap:
    """Simulate the paper scene along ``paper-b`` and map it (the default-map job body)."""
    run = simulate_default_run(progress=lambda f, m: progress(0.6 * f, m))
    progress(0.6, "mapping")
    wallmap = build_map([RunSource.from_run(run, name=f"builtin:{DEFAULT_SCENE}/"
                                                 f"{DEFAULT_MAP_PATH}@seed{DEFAULT_SEED}")],
                        BuildParams(method="paper"))
    maps.put(map_id, wallmap)
    return wallmap
