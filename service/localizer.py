"""The real tracker: a block through :func:`mapping.heatmap.doppler_heatmap` into a filter
from ``localization``. Conversions only; every number comes from those packages.

One :class:`~localization.sensor.SensorTables` per map is built on first use and shared by
all sessions on that map (read-only), rebuilt when the map file changes.
"""

from __future__ import annotations

import dataclasses
import threading
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localization.estimate import PoseEstimate
from localization.grid_filter import GridFilter
from localization.particle_filter import FilterConfig, ParticleFilter
from localization.sensor import SensorConfig, SensorTables, build_tables, validate_block
from mapping.heatmap import HeatMap, doppler_heatmap
from mapping.signal import SonarConfig
from service.engine import BlockInput, EstimateOut, FilterSpec
from service.mapstore import MapStore, map_config


def estimate_out(est: PoseEstimate) -> EstimateOut:
    """``localization`` estimate -> plain values."""

    def mat(a: NDArray[np.float64]) -> tuple[tuple[float, float, float], ...]:
        return tuple((float(r[0]), float(r[1]), float(r[2])) for r in np.asarray(a))

    values = np.concatenate([np.ravel(est.pose), np.ravel(est.cov), np.ravel(est.cov_all),
                             [est.ess]])
    if not np.all(np.isfinite(values)):
        # a numerical failure of the filter, not of the input: the store rolls the session
        # back and the client gets a 500 naming it (JSON cannot carry NaN anyway)
        raise FloatingPointError("the filter produced a non-finite estimate")
    return EstimateOut(
        pose=(float(est.pose[0]), float(est.pose[1]), float(est.pose[2])),
        covariance=mat(est.cov),
        modes=tuple((float(m.mean[0]), float(m.mean[1]), float(m.mean[2]), float(m.weight))
                    for m in est.modes),
        ess=float(est.ess), converged=bool(est.converged),
        direction_observable=bool(est.direction_observable),
        covariance_all=mat(est.cov_all),
        extra={"model": est.model, "updated": bool(est.updated),
               "likelihood_scale": float(est.likelihood_scale)},
    )


def block_heatmap(block: BlockInput, config: SonarConfig) -> HeatMap | None:
    """Heat map of a block (``None`` for an empty block: predict only).

    The block is bare (no neighbour samples: the next block does not exist yet); reads past
    its edges see zeros, which :func:`~mapping.heatmap.doppler_heatmap` documents as < 0.1 %
    of the peak.
    """
    if block.samples.size == 0:
        return None
    validate_block(block.samples, config.block_samples)
    return doppler_heatmap(block.samples, block.speed_m_s, config, workers=1)


class PFTracker:
    """A :class:`~localization.particle_filter.ParticleFilter` behind the Tracker protocol."""

    def __init__(self, pf: ParticleFilter, tables: SensorTables, config: SonarConfig) -> None:
        self.pf, self.tables, self.config = pf, tables, config

    def update(self, block: BlockInput) -> EstimateOut:
        hm = block_heatmap(block, self.config)
        est = self.pf.step(hm, block.speed_m_s, block.yaw_rate_rad_s,
                           block.dt_s)
        return estimate_out(est)

    def reinit_global(self) -> None:
        self.pf.reset_global()

    def state_dict(self) -> dict[str, Any]:
        return dict(self.pf.state_dict())

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.pf = ParticleFilter.from_state_dict(state, self.tables)

    def particles(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        w = np.exp(self.pf.log_w - self.pf.log_w.max())
        return self.pf.poses.copy(), w / w.sum()


class GridTracker:
    """The exact grid filter (:class:`~localization.grid_filter.GridFilter`) as a Tracker."""

    def __init__(self, gf: GridFilter, tables: SensorTables, config: SonarConfig) -> None:
        self.gf, self.tables, self.config = gf, tables, config

    def update(self, block: BlockInput) -> EstimateOut:
        hm = block_heatmap(block, self.config)
        return estimate_out(self.gf.step(hm, block.speed_m_s, block.yaw_rate_rad_s,
                                         block.dt_s))

    def reinit_global(self) -> None:
        self.gf.reset_global()

    def state_dict(self) -> dict[str, Any]:
        return dict(self.gf.state_dict())

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.gf = GridFilter.from_state_dict(state, self.tables)

    def particles(self) -> None:
        return None  # a histogram, not a particle set


#: Largest grid-filter belief (cells x headings) a session may hold: 4e6 states = 32 MB,
#: copied and checkpointed on every block. Larger maps need the particle filter.
MAX_GRID_STATES = 4_000_000


class LocalizationFactory:
    """Trackers on the maps of a :class:`~service.mapstore.MapStore`.

    Parameters
    ----------
    maps : MapStore
    sensor : SensorConfig, optional
        Sensor model shared by all sessions (default: ``localization``'s defaults).
    """

    def __init__(self, maps: MapStore, sensor: SensorConfig | None = None) -> None:
        self.maps = maps
        self.sensor = sensor or SensorConfig()
        self._tables: dict[str, tuple[int, SensorTables, SonarConfig]] = {}
        self._lock = threading.Lock()

    def tables(self, map_id: str) -> tuple[SensorTables, SonarConfig]:
        """Lookup tables and sonar config of ``map_id`` (cached per loaded map object)."""
        wallmap = self.maps.get(map_id)
        with self._lock:
            hit = self._tables.get(map_id)
            if hit is None or hit[0] != id(wallmap):
                hit = (id(wallmap), build_tables(wallmap, self.sensor), map_config(wallmap))
                self._tables[map_id] = hit
            return hit[1], hit[2]

    def _session_tables(self, map_id: str, spec: FilterSpec
                        ) -> tuple[SensorTables, SonarConfig]:
        """The map's tables, with the session's own sharpness if it asked for one (beta does
        not enter the tables, so this is a cheap copy of the config only)."""
        tables, config = self.tables(map_id)
        if spec.beta is not None:
            sensor = dataclasses.replace(tables.config, beta=float(spec.beta))
            tables = dataclasses.replace(tables, config=sensor)
        return tables, config

    def create(self, map_id: str, spec: FilterSpec) -> PFTracker | GridTracker:
        tables, config = self._session_tables(map_id, spec)
        pose = None if spec.initial_pose is None else np.asarray(spec.initial_pose)
        cov = None if spec.initial_covariance is None else np.asarray(spec.initial_covariance)
        if spec.kind == "grid":
            n_states = int(tables.free_mask.size) * tables.config.n_angles
            if n_states > MAX_GRID_STATES:
                raise ValueError(f"filter 'grid' needs {n_states} states on map {map_id!r}; "
                                 f"allowed <= {MAX_GRID_STATES} (use filter 'pf')")
            try:
                gf = GridFilter(tables, None, pose, cov)
            except np.linalg.LinAlgError:
                raise ValueError("initial_covariance must be invertible for filter 'grid'"
                                 ) from None
            return GridTracker(gf, tables, config)
        if spec.kind != "pf":
            raise ValueError(f"filter must be 'pf' or 'grid', got {spec.kind!r}")
        rng = np.random.default_rng(spec.seed)
        pf = ParticleFilter(tables, FilterConfig(n_particles=spec.particles), rng, pose, cov)
        return PFTracker(pf, tables, config)

    def restore(self, map_id: str, spec: FilterSpec,
                state: dict[str, Any]) -> PFTracker | GridTracker:
        tables, config = self._session_tables(map_id, spec)
        if spec.kind == "grid":
            return GridTracker(GridFilter.from_state_dict(state, tables), tables, config)
        return PFTracker(ParticleFilter.from_state_dict(state, tables), tables, config)

