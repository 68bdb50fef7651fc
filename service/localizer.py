"""The real tracker: a block through :func:`mapping.heatmap.doppler_heatmap` into a filter
from ``localization``, the core's :class:`~localization.estimate.PoseEstimate` out. Every
number comes from those packages; this module only wires them to the session store.

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
from localization.sensor import (
    SensorConfig,
    SensorTables,
    build_tables,
    resolve_model,
    validate_block,
)
from mapping.heatmap import HeatMap, doppler_heatmap
from mapping.signal import SonarConfig
from service.mapstore import MapStore, map_config
from service.sessions import BlockInput, FilterSpec, InvalidSpec


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


class Localizer:
    """A :class:`~localization.particle_filter.ParticleFilter` or the exact
    :class:`~localization.grid_filter.GridFilter` as the store's
    :class:`~service.sessions.Tracker`."""

    def __init__(self, filt: ParticleFilter | GridFilter, tables: SensorTables,
                 config: SonarConfig) -> None:
        self.filter, self.tables, self.config = filt, tables, config

    def update(self, block: BlockInput) -> PoseEstimate:
        return self.filter.step(block_heatmap(block, self.config), block.speed_m_s,
                                block.yaw_rate_rad_s, block.dt_s)

    def reinit_global(self) -> None:
        self.filter.reset_global()

    def state_dict(self) -> dict[str, Any]:
        return dict(self.filter.state_dict())

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.filter = type(self.filter).from_state_dict(state, self.tables)

    def particles(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        if not isinstance(self.filter, ParticleFilter):
            return None  # a histogram, not a particle set
        w = np.exp(self.filter.log_w - self.filter.log_w.max())
        return self.filter.poses.copy(), w / w.sum()


#: Largest grid-filter belief (cells x headings) a session may hold: 4e6 states = 32 MB,
#: copied and checkpointed on every block. Larger maps need the particle filter.
MAX_GRID_STATES = 4_000_000


class LocalizationFactory:
    """Localizers on the maps of a :class:`~service.mapstore.MapStore`.

    Parameters
    ----------
    maps : MapStore
    sensor : SensorConfig, optional
        Sensor model shared by all sessions (default: the physical ``echo`` model; a map
        without walls gets the G ``correlation`` model with the same other settings).
    """

    def __init__(self, maps: MapStore, sensor: SensorConfig | None = None) -> None:
        self.maps = maps
        self.sensor = sensor or SensorConfig(model="echo")
        self._tables: dict[str, tuple[int, SensorTables, SonarConfig]] = {}
        self._lock = threading.Lock()

    def tables(self, map_id: str) -> tuple[SensorTables, SonarConfig]:
        """Lookup tables and sonar config of ``map_id`` (cached per loaded map object)."""
        wallmap = self.maps.get(map_id)
        with self._lock:
            hit = self._tables.get(map_id)
            if hit is None or hit[0] != id(wallmap):
                sonar = map_config(wallmap)
                model = resolve_model(wallmap, "auto") if self.sensor.model == "echo" \
                    else self.sensor.model
                sensor = dataclasses.replace(self.sensor, model=model)
                hit = (id(wallmap), build_tables(wallmap, sensor, sonar=sonar), sonar)
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

    def create(self, map_id: str, spec: FilterSpec) -> Localizer:
        """A new localizer; :class:`~service.sessions.InvalidSpec` names the field the filter
        refuses (the request schema has already checked each field on its own)."""
        if spec.kind not in ("pf", "grid"):
            raise InvalidSpec("filter", f"filter must be 'pf' or 'grid', got {spec.kind!r}",
                              "pf or grid")
        tables, config = self._session_tables(map_id, spec)
        pose = None if spec.initial_pose is None else np.asarray(spec.initial_pose)
        cov = None if spec.initial_covariance is None else np.asarray(spec.initial_covariance)
        if spec.kind == "grid":
            n_states = int(tables.free_mask.size) * tables.config.n_angles
            if n_states > MAX_GRID_STATES:
                raise InvalidSpec("filter", f"filter 'grid' needs {n_states} states on map "
                                  f"{map_id!r}", f"<= {MAX_GRID_STATES} states (else 'pf')")
            try:
                return Localizer(GridFilter(tables, None, pose, cov), tables, config)
            except np.linalg.LinAlgError:
                raise InvalidSpec("initial_covariance", "initial_covariance must be invertible "
                                  "for filter 'grid'", "a positive definite 3x3") from None
        rng = np.random.default_rng(spec.seed)
        pf = ParticleFilter(tables, FilterConfig(n_particles=spec.particles), rng, pose, cov)
        return Localizer(pf, tables, config)

    def restore(self, map_id: str, spec: FilterSpec, state: dict[str, Any]) -> Localizer:
        tables, config = self._session_tables(map_id, spec)
        cls = GridFilter if spec.kind == "grid" else ParticleFilter
        return Localizer(cls.from_state_dict(state, tables), tables, config)
