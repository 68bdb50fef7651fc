"""Exact grid (histogram) Bayes filter over (x, y, heading): the reference posterior.

The belief is a probability mass on every map cell (at the map resolution) times
``n_angles`` heading bins (5 deg by default), restricted to the free space. "Model no more
than a scene needs": for a small room (5 m x 5 m at 5 cm and 5 deg: ~720k states) this is
exact up to the discretization, so the particle filter must agree with it.

predict  the odometry arc applied to every heading slice (bilinear shift of the position
         mass, linear split between heading bins), then Gaussian blur with the motion
         model's standard deviations (position isotropic, heading circular);
update   every free cell and every heading scored at once by
         :func:`localization.sensor.score_cells_all_headings` (circular correlation along
         the angle axis), floored relative to the best state as in the particle filter.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from localization import motion
from localization.estimate import ClusterConfig, PoseEstimate, default_start_cov, summarize
from localization.motion import MotionNoise
from localization.sensor import (
    SensorTables,
    log_likelihood,
    prepare_measurement,
    score_cells_all_headings,
)
from mapping.angles import wrap_angle
from mapping.heatmap import HeatMap

FloatArray = NDArray[np.float64]
STATE_FORMAT = "omnisonar-grid-state-1"


@dataclass(frozen=True)
class GridConfig:
    """Grid filter parameters.

    Parameters
    ----------
    motion : MotionNoise
    cluster : ClusterConfig
    min_mass : float
        States lighter than this are left out of the mode summary (speed only).
    """

    motion: MotionNoise = field(default_factory=MotionNoise)
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    min_mass: float = 1e-9


def state_poses(tables: SensorTables) -> FloatArray:
    """Poses (n_free * n_angles, 3) of the grid states, free cells major, heading minor."""
    cells = np.argwhere(tables.free_mask)
    n_h = tables.config.n_angles
    x = tables.origin_m[0] + cells[:, 1] * tables.resolution_m
    y = tables.origin_m[1] + cells[:, 0] * tables.resolution_m
    h = wrap_angle(2 * np.pi * np.arange(n_h) / n_h)
    return np.column_stack([np.repeat(x, n_h), np.repeat(y, n_h), np.tile(h, x.size)])


def predict(belief: FloatArray, speed_m_s: float, yaw_rate_rad_s: float, dt_s: float,
            tables: SensorTables, noise: MotionNoise) -> FloatArray:
    """Motion update of a dense belief (ny, nx, n_h); returns a new normalized array."""
    rot1, trans, rot2 = motion.odometry_increment(speed_m_s, yaw_rate_rad_s, dt_s)
    if trans == 0.0 and rot1 == 0.0 and rot2 == 0.0:
        return belief.copy()
    n_h = belief.shape[2]
    dh = 2 * np.pi / n_h
    res = tables.resolution_m
    out = np.zeros_like(belief)
    shift_bins = (rot1 + rot2) / dh
    lo = math.floor(shift_bins)
    frac = shift_bins - lo
    for h in range(n_h):
        ang = h * dh + rot1
        moved = ndimage.shift(belief[:, :, h], (trans * math.sin(ang) / res,
                                                trans * math.cos(ang) / res),
                              order=1, mode="constant", cval=0.0, prefilter=False)
        out[:, :, (h + lo) % n_h] += (1 - frac) * moved
        out[:, :, (h + lo + 1) % n_h] += frac * moved
    s1, st, s2 = motion.motion_std(rot1, trans, rot2, noise)
    sigma_xy = math.hypot(st, abs(trans) * s1) / res
    sigma_h = math.hypot(s1, s2) / dh
    if sigma_xy > 1e-3:
        out = ndimage.gaussian_filter(out, (sigma_xy, sigma_xy, 0.0), mode="constant")
    if sigma_h > 1e-3:
        out = ndimage.gaussian_filter1d(out, sigma_h, axis=2, mode="wrap")
    out *= tables.free_mask[:, :, None]
    total = out.sum()
    if total <= 0:
        raise ValueError("the motion moved all belief off the free space")
    return np.asarray(out / total)


class GridFilter:
    """Histogram filter on the map's free cells x ``n_angles`` headings.

    Parameters
    ----------
    tables : SensorTables
    config : GridConfig
    pose, cov : array-like, optional
        Tracked initialization (Gaussian); without them the belief starts uniform.
    """

    def __init__(self, tables: SensorTables, config: GridConfig | None = None,
                 pose: FloatArray | None = None, cov: FloatArray | None = None) -> None:
        self.tables = tables
        self.config = GridConfig() if config is None else config
        self.cells = np.argwhere(tables.free_mask)
        self.poses = state_poses(tables)
        self.n_steps = 0
        if pose is None:
            self.reset_global()
        else:
            self.reset_tracked(pose, default_start_cov()
                               if cov is None else cov)

    @property
    def shape(self) -> tuple[int, int, int]:
        """(ny, nx, n_headings) of the dense belief."""
        return (*self.tables.shape, self.tables.config.n_angles)

    def reset_global(self) -> None:
        """Uniform belief over the free space and all headings."""
        b = np.zeros(self.shape)
        b[self.tables.free_mask] = 1.0
        self.belief = b / b.sum()

    def reset_tracked(self, pose: FloatArray, cov: FloatArray) -> None:
        """Gaussian belief around ``pose`` (3,) with covariance ``cov`` (3, 3)."""
        pose = np.asarray(pose, dtype=np.float64)
        d = self.poses - pose
        d[:, 2] = wrap_angle(d[:, 2])
        q = np.einsum("ij,jk,ik->i", d, np.linalg.inv(np.asarray(cov, dtype=np.float64)), d)
        b = np.zeros(self.shape)
        b[self.tables.free_mask] = np.exp(-0.5 * (q - q.min())).reshape(-1, self.shape[2])
        self.belief = b / b.sum()

    def step(self, heat_map: HeatMap | None, speed_m_s: float, yaw_rate_rad_s: float,
             dt_s: float) -> PoseEstimate:
        """Predict with the odometry, then weigh by the heat map (None: predict only).

        Raises ``ValueError`` (state unchanged) on a bad heat map or odometry.
        """
        motion.odometry_increment(speed_m_s, yaw_rate_rad_s, dt_s)
        meas = None if heat_map is None else prepare_measurement(heat_map, self.tables.config)
        belief = predict(self.belief, speed_m_s, yaw_rate_rad_s, dt_s, self.tables,
                         self.config.motion)
        if meas is not None:
            rho = score_cells_all_headings(self.tables, meas, self.cells)
            ll = log_likelihood(rho, self.tables.config, float(np.nanmax(rho)))
            post = belief[self.tables.free_mask] * np.exp(ll - ll.max())
            belief = np.zeros_like(belief)
            belief[self.tables.free_mask] = post / post.sum()
        self.belief = belief
        self.n_steps += 1
        w = belief[self.tables.free_mask].ravel()
        keep = w > self.config.min_mass * w.max()
        log_w = np.log(w[keep] / w[keep].sum())
        return summarize(
            self.poses[keep], log_w, self.config.cluster, ess=float(np.exp(-np.log(
                np.sum(np.exp(2 * log_w))))),
            direction_observable=bool(meas is not None and meas.direction_observable),
            updated=meas is not None, model="none" if meas is None else meas.model)

    def marginal_xy(self) -> FloatArray:
        """Position marginal (ny, nx)."""
        return np.asarray(self.belief.sum(axis=2))

    def state_dict(self) -> dict[str, NDArray[Any]]:
        """The belief as numpy arrays."""
        return {"format": np.array(STATE_FORMAT), "belief": self.belief.copy(),
                "n_steps": np.array(self.n_steps)}

    @classmethod
    def from_state_dict(cls, state: Mapping[str, NDArray[Any]], tables: SensorTables,
                        config: GridConfig | None = None) -> GridFilter:
        """Rebuild from :meth:`state_dict` on the same map's tables."""
        if str(state.get("format", "")) != STATE_FORMAT:
            raise ValueError(f"state 'format' must be {STATE_FORMAT!r}")
        gf = cls(tables, config)
        belief = np.asarray(state["belief"], dtype=np.float64)
        if belief.shape != gf.shape:
            raise ValueError(f"state 'belief' must have shape {gf.shape}, got {belief.shape}")
        gf.belief = belief.copy()
        gf.n_steps = int(state["n_steps"])
        return gf
