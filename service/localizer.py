"""The real tracker: a block through :func:`mapping.heatmap.doppler_heatmap` into a filter
from ``localization``, the core's :class:`~localization.estimate.PoseEstimate` out. Every
number comes from those packages; this module only wires them to the session store.

One :class:`~localization.sensor.SensorTables` per map is built on first use and shared by
all sessions on that map (read-only), rebuilt when the map file changes.
"""

from __future__ import annotations

import dataclasses
import threading
import weakref
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
from service.sessions import BlockInput, FilterSpec, InvalidSpec, MapChanged


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
        self.base_tables = tables  # the map's shared tables (kept alive while in use)
        # the live view (service.routers.view) sets keep_heatmap while someone watches
        self.keep_heatmap = False
        self.last_heatmap: HeatMap | None = None

    def update(self, block: BlockInput) -> PoseEstimate:
        # the echo model reads a denser bank than the map's (SensorConfig.heatmap_sonar)
        hm = block_heatmap(block, self.tables.config.heatmap_sonar(self.config))
        if self.keep_heatmap:
            self.last_heatmap = hm
        return self.filter.step(hm, block.speed_m_s, block.yaw_rate_rad_s, block.dt_s)

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
        # weak: a map's tables live as long as some session holds them, then are released
        self._tables: weakref.WeakValueDictionary[tuple[str, str], SensorTables]
        self._tables = weakref.WeakValueDictionary()
        self._lock = threading.Lock()

    def tables(self, map_id: str, sha256: str | None = None) -> tuple[SensorTables, SonarConfig]:
        """Lookup tables and sonar config of ``map_id`` (shared per map content while in
        use); :class:`~service.sessions.MapChanged` if the file's SHA-256 is not ``sha256``."""
        wallmap, digest = self.maps.load(map_id)
        if sha256 is not None and digest != sha256:
            raise MapChanged(map_id, f"map {map_id!r} was replaced since the session started "
                             f"(sha256 {sha256[:12]}... -> {digest[:12]}...)")
        sonar = map_config(wallmap)
        with self._lock:
            tables = self._tables.get((map_id, digest))
            if tables is None:
                model = resolve_model(wallmap, "auto") if self.sensor.model == "echo" \
                    else self.sensor.model
                sensor = dataclasses.replace(self.sensor, model=model)
                tables = build_tables(wallmap, sensor, sonar=sonar)
                self._tables[(map_id, digest)] = tables
            return tables, sonar

    def _session_tables(self, map_id: str, spec: FilterSpec
                        ) -> tuple[SensorTables, SonarConfig, SensorTables]:
        """The map's tables, with the session's own sharpness and speed of sound if it asked
        for them (neither enters the tables' arrays, so this is a cheap copy of the configs:
        the heat map's range axis and the echo model's delays and Doppler read the speed of
        sound from ``config`` and ``tables.sonar``)."""
        base, config = self.tables(map_id, spec.map_sha256)
        tables = base
        if (spec.beta is not None or spec.sonar_height_m is not None
                or spec.ceiling_height_m is not None):
            try:
                sensor = dataclasses.replace(
                    base.config, sonar_height_m=spec.sonar_height_m,
                    ceiling_height_m=spec.ceiling_height_m,
                    beta=base.config.beta if spec.beta is None else float(spec.beta))
            except ValueError as exc:
                raise InvalidSpec("ceiling_height_m", str(exc),
                                  "above sonar_height_m") from None
            tables = dataclasses.replace(base, config=sensor)
        if spec.sound_speed_m_s is not None:
            config = dataclasses.replace(config, sound_speed_m_s=float(spec.sound_speed_m_s))
            tables = dataclasses.replace(tables, sonar=config)
        return tables, config, base

    def create(self, map_id: str, spec: FilterSpec) -> Localizer:
        """A new localizer; :class:`~service.sessions.InvalidSpec` names the field the filter
        refuses (the request schema has already checked each field on its own)."""
        if spec.kind not in ("pf", "grid"):
            raise InvalidSpec("filter", f"filter must be 'pf' or 'grid', got {spec.kind!r}",
                              "pf or grid")
        tables, config, base = self._session_tables(map_id, spec)
        pose = None if spec.initial_pose is None else np.asarray(spec.initial_pose)
        cov = None if spec.initial_covariance is None else np.asarray(spec.initial_covariance)
        if spec.kind == "grid":
            n_states = int(tables.free_mask.size) * tables.config.n_angles
            if n_states > MAX_GRID_STATES:
                raise InvalidSpec("filter", f"filter 'grid' needs {n_states} states on map "
                                  f"{map_id!r}", f"<= {MAX_GRID_STATES} states (else 'pf')")
            try:
                return _pinned(base, Localizer(GridFilter(tables, None, pose, cov), tables,
                                              config))
            except np.linalg.LinAlgError:
                raise InvalidSpec("initial_covariance", "initial_covariance must be invertible "
                                  "for filter 'grid'", "a positive definite 3x3") from None
        rng = np.random.default_rng(spec.seed)
        pf = ParticleFilter(tables, FilterConfig(n_particles=spec.particles,
                                                 open_map_global=spec.open_map), rng, pose, cov)
        return _pinned(base, Localizer(pf, tables, config))

    def restore(self, map_id: str, spec: FilterSpec, state: dict[str, Any]) -> Localizer:
        tables, config, base = self._session_tables(map_id, spec)
        cls = GridFilter if spec.kind == "grid" else ParticleFilter
        return _pinned(base, Localizer(cls.from_state_dict(state, tables), tables, config))


def _pinned(base: SensorTables, localizer: Localizer) -> Localizer:
    """Let ``localizer`` hold the map's shared tables (a session with its own beta holds a
    copy with another config, which alone would let the shared cache entry go)."""
    localizer.base_tables = base
    return localizer
