"""Forward models: scene + path -> run (issue 3).

``simulate_run(scene, trajectory, config, n_blocks, engine_config, rng)`` picks the engine
from the type of ``engine_config`` (:class:`IsmConfig`: the image-source engine of
:mod:`mapping.simulate.ism`; an FDTD config can register itself in :data:`ENGINES`) and
returns a :class:`~mapping.runfile.Run`. ``iter_blocks`` is the same as a generator, for
progress bars and for stopping early.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from mapping.run import Run
from mapping.signal import SonarConfig
from mapping.simulate._base import (
    PathTable,
    SceneLike,
    SimBlock,
    TrajectoryLike,
    assemble_run,
    block_mean_odometry,
)
from mapping.simulate.fdtd import FdtdConfig, iter_fdtd_blocks
from mapping.simulate.ism import IsmConfig, iter_ism_blocks

__all__ = [
    "ENGINES",
    "PathTable",
    "SceneLike",
    "SimBlock",
    "TrajectoryLike",
    "assemble_run",
    "block_mean_odometry",
    "engine_name",
    "iter_blocks",
    "run_meta",
    "simulate_run",
]

BlockIterator = Callable[..., Iterator[SimBlock]]

#: Engine name -> (config type, block generator): the image-source default and the FDTD reference.
ENGINES: dict[str, tuple[type, BlockIterator]] = {
    "ism": (IsmConfig, iter_ism_blocks),
    "fdtd": (FdtdConfig, iter_fdtd_blocks),
}


def engine_name(engine_config: Any) -> str:
    """Name of the engine whose config type ``engine_config`` is; ``ValueError`` if none."""
    for name, (cls, _) in ENGINES.items():
        if isinstance(engine_config, cls):
            return name
    raise ValueError(
        f"engine_config must be one of {[c.__name__ for c, _ in ENGINES.values()]}, "
        f"got {type(engine_config).__name__}"
    )


def iter_blocks(
    scene: SceneLike,
    trajectory: TrajectoryLike,
    config: SonarConfig,
    n_blocks: int,
    engine_config: Any,
    rng: np.random.Generator,
) -> Iterator[SimBlock]:
    """Simulated blocks 0 .. n_blocks - 1 in order, from the engine of ``engine_config``."""
    _, generator = ENGINES[engine_name(engine_config)]
    return generator(scene, trajectory, config, n_blocks, engine_config, rng)


def run_meta(
    scene: SceneLike,
    trajectory: TrajectoryLike,
    engine_config: Any,
    seed: int | None,
    blocks: list[SimBlock] | None = None,
) -> dict[str, Any]:
    """Run-file metadata: engine, its parameters, scene and path names, seed, order."""
    meta: dict[str, Any] = {
        "engine": engine_name(engine_config),
        "engine_config": engine_config.to_dict() if hasattr(engine_config, "to_dict") else {},
        "scene_name": getattr(scene, "name", None),
        "path": getattr(trajectory, "name", None),
        "seed": seed,
        "spreading": getattr(engine_config, "spreading", None),
        "direct_path": False,
    }
    if blocks:
        # highest reflection order actually rendered, and the largest path count per block
        for key in ("order", "n_paths", "order_limit", "order_truncated"):
            values = [b.meta[key] for b in blocks if key in b.meta]
            if values:
                meta[key] = max(values)
    return meta


def simulate_run(
    scene: SceneLike,
    trajectory: TrajectoryLike,
    config: SonarConfig,
    n_blocks: int,
    engine_config: Any,
    rng: np.random.Generator,
    seed: int | None = None,
) -> Run:
    """Simulate ``n_blocks`` blocks along ``trajectory`` in ``scene`` and return the run.

    ``pose`` holds the ground truth at block midpoints and ``scene`` the scene JSON;
    ``meta`` names the engine, path, seed (if given), order and spreading.
    """
    blocks = list(iter_blocks(scene, trajectory, config, n_blocks, engine_config, rng))
    meta = run_meta(scene, trajectory, engine_config, seed, blocks)
    return assemble_run(blocks, config, scene.to_json(), meta)
