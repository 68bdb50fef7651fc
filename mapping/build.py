"""Batch map building over many runs: processes, or a dask.distributed cluster.

Work is split per run: each run's heat maps are computed and reduced where the run is
(a partial G on the run's own aligned extent for the paper method, the compact polar
observations for the inverse method), then the main process combines the results **in the
order the runs were given**, so the map is bit-identical whatever the number of workers or the
scheduler.

Runs are handed over as :class:`RunSource` objects (a picklable loader plus a name and a
checksum for provenance) so this module never opens a file path itself; the CLI builds them
with ``functools.partial(mapping.runfile.read_run, path)``.
"""

from __future__ import annotations

import functools
import multiprocessing
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.coverage import coverage_mask
from mapping.grid import GridExtent, GridParams, accumulate, map_extent, union_extent
from mapping.heatmap import HeatMap, heatmap_of_run
from mapping.reconstruct import (
    InverseParams,
    Observations,
    concat_observations,
    observations_from_heatmaps,
    reconstruct_inverse,
)
from mapping.run import Run
from mapping.signal import SonarConfig
from mapping.wallmap import WallMap, rasterize_walls
from mapping.walls import (
    FittedWalls,
    PeakObservations,
    WallFitParams,
    concat_peaks,
    fit_walls,
    run_peaks,
)

FloatArray = NDArray[np.float64]
METHODS = ("walls", "paper", "inverse")


@dataclass(frozen=True)
class RunSource:
    """A run to map: ``load()`` returns the :class:`Run`; name and checksum go to provenance."""

    load: Callable[[], Run]
    name: str
    sha256: str = ""

    @classmethod
    def from_run(cls, run: Run, name: str = "<memory>") -> RunSource:
        """Wrap an in-memory run (picklable, so it works with process pools too)."""
        return cls(load=functools.partial(_identity, run), name=name)


def _identity(run: Run) -> Run:
    return run


@dataclass(frozen=True)
class BuildParams:
    """What to build: the method and its parameters."""

    method: str = "paper"
    grid: GridParams = field(default_factory=GridParams)
    inverse: InverseParams = field(default_factory=InverseParams)
    walls: WallFitParams = field(default_factory=WallFitParams)
    heatmap_kwargs: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON parameters of the chosen method (stored in the map file)."""
        d: dict[str, Any] = {"grid": self.grid.to_dict()}
        if self.method == "inverse":
            d["inverse"] = self.inverse.to_dict()
        if self.method == "walls":
            d["walls"] = asdict(self.walls)
        if self.heatmap_kwargs:
            d["heatmap"] = dict(self.heatmap_kwargs)
        return d


@dataclass(frozen=True)
class RunResult:
    """What one run contributes (computed in a worker)."""

    name: str
    sha256: str
    sonar: str
    counts: dict[str, int]
    extent: GridExtent | None = None
    G: FloatArray | None = None
    observations: Observations | None = None
    peaks: PeakObservations | None = None
    poses: FloatArray | None = None


def run_heatmaps(run: Run, **kwargs: Any) -> Iterator[HeatMap | None]:
    """Heat map of every block (with its neighbours' samples); None for untracked blocks."""
    tracked = np.asarray(np.isfinite(run.pose).all(axis=1))
    for k in range(run.n_blocks):
        yield heatmap_of_run(run, k, **kwargs) if bool(tracked[k]) else None


def process_run(source: RunSource, params: BuildParams) -> RunResult:
    """Heat maps of one run reduced to its contribution (runs in a worker process)."""
    run = source.load()
    kwargs = dict(params.heatmap_kwargs)
    tracked = np.isfinite(run.pose).all(axis=1)
    name, sha, sonar = source.name, source.sha256, run.config.to_json()
    if not tracked.any():
        counts = {"blocks_used": 0, "blocks_untracked": run.n_blocks, "blocks_unobservable": 0}
        return RunResult(name, sha, sonar, counts)
    if params.method == "paper":
        G, extent, counts = accumulate(run_heatmaps(run, **kwargs), run.pose, params.grid)
        return RunResult(name, sha, sonar, counts, extent=extent, G=G)
    if params.method == "walls":
        return _walls_result(run, source, params)
    obs, counts = observations_from_heatmaps(run_heatmaps(run, **kwargs), run.pose,
                                             params.grid, params.inverse, config=run.config)
    return RunResult(name, sha, sonar, counts, observations=obs)


def _walls_result(run: Run, source: RunSource, params: BuildParams) -> RunResult:
    peaks = run_peaks(run, 0, params.walls.peaks)
    tracked = np.isfinite(run.pose).all(axis=1)
    used = np.unique(peaks.block).size
    counts = {"blocks_used": int(used), "blocks_untracked": int((~tracked).sum()),
              "blocks_unobservable": int(tracked.sum() - used)}
    return RunResult(source.name, source.sha256, run.config.to_json(), counts, peaks=peaks,
                     poses=run.pose[tracked])


def check_same_config(results: Sequence[RunResult]) -> SonarConfig:
    """The common SonarConfig of all runs; ValueError naming the first run that differs."""
    first = results[0]
    for r in results[1:]:
        if r.sonar != first.sonar:
            a, b = SonarConfig.from_json(first.sonar), SonarConfig.from_json(r.sonar)
            diff = {k: (v, getattr(b, k)) for k, v in a.to_dict().items()
                    if v != b.to_dict()[k]}
            raise ValueError(
                f"runs have different sonar configs and cannot share one map: {r.name} differs "
                f"from {first.name} in {diff}")
    return SonarConfig.from_json(first.sonar)


def combine(results: Sequence[RunResult], params: BuildParams) -> WallMap:
    """Reduce per-run results in the given order into one :class:`WallMap`."""
    if not results:
        raise ValueError("no runs to map")
    config = check_same_config(results)
    counts = {k: sum(r.counts[k] for r in results) for k in results[0].counts}
    provenance = {"runs": [{"path": r.name, "sha256": r.sha256, **r.counts} for r in results],
                  **counts}
    if counts["blocks_used"] == 0:
        slow = (f" (method 'walls' needs |speed| >= {params.walls.peaks.min_speed_m_s} m/s)"
                if params.method == "walls" else "")
        raise ValueError(f"no tracked, observable block in any run{slow}: nothing to map")
    if params.method == "walls":
        return _combine_walls(results, params, config, provenance)
    if params.method == "paper":
        parts = [r for r in results if r.G is not None and r.extent is not None]
        extent = union_extent([r.extent for r in parts if r.extent is not None])
        G = extent.zeros()
        for r in parts:
            assert r.G is not None and r.extent is not None
            _add_aligned(G, extent, r.G, r.extent)
    else:
        obs = concat_observations([r.observations for r in results
                                   if r.observations is not None])
        extent = map_extent(obs.poses, params.grid.radius_m, params.grid.resolution_m)
        G, info = reconstruct_inverse(obs, extent, params.grid, params.inverse)
        provenance["solver"] = info
    return WallMap(G=G, origin_m=extent.origin_m, resolution_m=extent.resolution_m,
                   sonar=config.to_json(), method=params.method, params=params.to_dict(),
                   provenance=provenance)


def _combine_walls(results: Sequence[RunResult], params: BuildParams, config: SonarConfig,
                   provenance: dict[str, Any]) -> WallMap:
    """Fit walls to the peaks of all runs; G is the fitted walls drawn on the grid."""
    parts = []
    for i, r in enumerate(results):
        if r.peaks is not None:
            parts.append(PeakObservations(**{**r.peaks.__dict__,
                                             "run": np.full(r.peaks.size, i, dtype=np.int64)}))
    peaks = concat_peaks(parts)
    fitted = fit_walls(peaks, config, params.walls)
    poses = np.concatenate([r.poses for r in results if r.poses is not None])
    extent = map_extent(poses, params.grid.radius_m, params.grid.resolution_m)
    G = extent.zeros()
    x = np.asarray(extent.origin_m[0] + extent.resolution_m * np.arange(extent.shape[1]),
                   dtype=np.float64)
    y = np.asarray(extent.origin_m[1] + extent.resolution_m * np.arange(extent.shape[0]),
                   dtype=np.float64)
    for wall, s in zip(fitted.walls_m, fitted.strength, strict=True):
        G = np.maximum(G, s * rasterize_walls(wall[None], x, y))
    coverage = coverage_mask(poses, x, y, params.walls.peaks.max_range_m, fitted.walls_m)
    provenance["fit"] = _fit_summary(fitted)
    return WallMap(G=G, origin_m=extent.origin_m, resolution_m=extent.resolution_m,
                   sonar=config.to_json(), method=params.method, params=params.to_dict(),
                   provenance=provenance, walls_m=fitted.walls_m,
                   wall_strength=np.abs(fitted.strength), wall_sigma=fitted.sigma,
                   wall_ambiguous=fitted.ambiguous, wall_pair=fitted.pair, coverage=coverage)


def _fit_summary(fitted: FittedWalls) -> dict[str, Any]:
    return {"walls": fitted.n, "candidates": fitted.n_candidates,
            "ambiguous": int(fitted.ambiguous.sum()),
            "explained_share": round(fitted.explained_share, 4),
            "peaks_per_wall": fitted.n_peaks.tolist(), "warning": fitted.warning,
            "heard_side": fitted.side.tolist(),
            "end_sigma_m": np.round(fitted.end_sigma, 4).tolist()}


def _add_aligned(G: FloatArray, extent: GridExtent, part: FloatArray, at: GridExtent) -> None:
    res = extent.resolution_m
    ix = int(round((at.origin_m[0] - extent.origin_m[0]) / res))
    iy = int(round((at.origin_m[1] - extent.origin_m[1]) / res))
    G[iy:iy + part.shape[0], ix:ix + part.shape[1]] += part


def build_map(
    sources: Sequence[RunSource], params: BuildParams | None = None, workers: int = 1,
    scheduler: str | None = None, client: Any = None,
    progress: Callable[[RunResult], None] | None = None, executor: Executor | None = None,
) -> WallMap:
    """Map from many runs, in parallel; bit-identical whatever ``workers``/scheduler.

    Parameters
    ----------
    sources : sequence of RunSource
    params : BuildParams, optional
    workers : int
        Processes (1 = in this process).
    scheduler : str, optional
        Address of a dask.distributed scheduler (needs the ``cluster`` extra).
    client : distributed.Client, optional
        An existing dask client (tests use an in-process LocalCluster).
    progress : callable, optional
        Called with each run's result as it completes (e.g. to advance a progress bar).
    executor : concurrent.futures.Executor, optional
        An existing pool to use instead of starting ``workers`` processes.

    Raises
    ------
    ValueError
        On differing sonar configs, no tracked block, bad ``workers``.
    """
    params = params or BuildParams()
    if not 1 <= workers <= 256:
        raise ValueError(f"workers must be in 1..256, got {workers}")
    if not sources:
        raise ValueError("sources must name at least one run")
    results: list[RunResult | None] = [None] * len(sources)
    if client is not None or scheduler is not None:
        _run_dask(sources, params, results, scheduler, client, progress)
    elif executor is not None:
        _run_pool(executor, sources, params, results, progress)
    elif workers == 1:
        for i, s in enumerate(sources):
            results[i] = process_run(s, params)
            if progress:
                progress(results[i])  # type: ignore[arg-type]
    else:
        # spawn, not fork: forking a process whose numba kernels started OpenMP threads aborts
        with process_pool(workers) as pool:
            _run_pool(pool, sources, params, results, progress)
    return combine([r for r in results if r is not None], params)


def process_pool(workers: int) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes (forking after numba's OpenMP threads aborts)."""
    return ProcessPoolExecutor(max_workers=workers,
                               mp_context=multiprocessing.get_context("spawn"))


def _run_pool(pool: Executor, sources: Sequence[RunSource], params: BuildParams,
              results: list[Any], progress: Callable[[RunResult], None] | None) -> None:
    futures = {pool.submit(process_run, s, params): i for i, s in enumerate(sources)}
    for fut in as_completed(futures):
        results[futures[fut]] = fut.result()
        if progress:
            progress(results[futures[fut]])


def _run_dask(sources: Sequence[RunSource], params: BuildParams, results: list[Any],
              scheduler: str | None, client: Any,
              progress: Callable[[RunResult], None] | None) -> None:
    try:
        from distributed import Client, as_completed
    except ImportError as exc:  # pragma: no cover - depends on the optional extra
        raise ValueError("--scheduler needs dask.distributed: pip install 'omnisonar[cluster]'"
                         ) from exc
    own = client is None
    client = client or Client(scheduler)
    try:
        futures = client.map(process_run, list(sources), params=params, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in as_completed(futures):
            results[index[fut.key]] = fut.result()
            if progress:
                progress(results[index[fut.key]])
    finally:
        if own:
            client.close()
