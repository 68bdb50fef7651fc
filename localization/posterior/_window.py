"""Poses, odometry windows, the window likelihood and the pose prior of the posterior.

Building blocks of :mod:`localization.posterior`: angle and circular helpers, the exact arc
composition of odometry (``u_k``), the window log-likelihood

    sum_k log L(H_k | theta (+) u_k, G)

of the localization sensor model (issue 6; heat map of paper Sec. 2.1, eq. 1, against the map
G of eq. 5) and the uniform :class:`PosePrior`. Every likelihood is a callable
``poses (n, 3) -> (n,)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localization.sensor import (
    SensorTables,
    heatmap_run,
    pose_log_likelihood,
    prepare_measurement,
)
from mapping.angles import wrap_angle
from mapping.heatmap import HeatMap, heatmap_of_run
from mapping.run import Run

FloatArray = NDArray[np.float64]
LogLikelihood = Callable[[FloatArray], FloatArray]
"""``poses (n, 3) [x_m, y_m, heading_rad] -> log-likelihood (n,)``; heading arrives wrapped."""

NDIM = 3
TWO_PI = 2.0 * math.pi


# ---- angles and poses -----------------------------------------------------------------
def _unwrap_about(pts: FloatArray, center: float) -> FloatArray:
    out = np.array(pts, dtype=np.float64)
    out[:, 2] = center + wrap_angle(out[:, 2] - center)
    out[:, 2] = np.where(out[:, 2] >= center + math.pi, out[:, 2] - TWO_PI, out[:, 2])
    return out


def arc_offset(speed_m_s: float, yaw_rate_rad_s: float, duration_s: float) -> FloatArray:
    """Pose change (forward_m, left_m, dheading_rad) of constant speed and yaw rate.

    Exact unicycle arc: forward = v sin(w t) / w, left = v (1 - cos(w t)) / w, dheading = w t,
    written with ``sinc`` so that w -> 0 gives the straight line v t.
    """
    a = yaw_rate_rad_s * duration_s
    d = speed_m_s * duration_s
    return np.array([d * np.sinc(a / math.pi), d * 0.5 * a * np.sinc(a / TWO_PI) ** 2, a])


def compose(poses: FloatArray, offset: FloatArray) -> FloatArray:
    """Poses (n, 3) moved by ``offset`` (forward_m, left_m, dheading_rad) in their own frame."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    out = np.empty_like(poses)
    out[:, 0] = poses[:, 0] + c * offset[0] - s * offset[1]
    out[:, 1] = poses[:, 1] + s * offset[0] + c * offset[1]
    out[:, 2] = wrap_angle(poses[:, 2] + offset[2])
    return out


def invert(offset: FloatArray) -> FloatArray:
    """The inverse pose change: ``compose(compose(p, o), invert(o)) == p``."""
    c, s = math.cos(offset[2]), math.sin(offset[2])
    return np.array([-c * offset[0] - s * offset[1], s * offset[0] - c * offset[1], -offset[2]])


def window_offsets(
    speed_m_s: FloatArray, yaw_rate_rad_s: FloatArray, block_s: float, anchor: int = 0
) -> FloatArray:
    """Offsets (K, 3) of the midpoint poses of K consecutive blocks from block ``anchor``.

    Between midpoints k-1 and k the robot drives the second half of block k-1 and the first
    half of block k, each at that block's odometry. Row ``anchor`` is zero; ``anchor=0``
    parametrizes the window by its first pose, ``anchor=K-1`` by its last (the filter's).
    """
    v = np.asarray(speed_m_s, dtype=np.float64)
    w = np.asarray(yaw_rate_rad_s, dtype=np.float64)
    if v.ndim != 1 or v.shape != w.shape or v.size < 1:
        raise ValueError(
            f"speed_m_s and yaw_rate_rad_s must be equal-length 1-D arrays with >= 1 block, "
            f"got shapes {v.shape} and {w.shape}"
        )
    if not block_s > 0:
        raise ValueError(f"block_s must be > 0, got {block_s}")
    if not 0 <= anchor < v.size:
        raise ValueError(f"anchor must be in 0..{v.size - 1}, got {anchor}")
    out = np.zeros((v.size, NDIM))
    pose = np.zeros((1, NDIM))
    for k in range(1, v.size):
        pose = compose(pose, arc_offset(v[k - 1], w[k - 1], 0.5 * block_s))
        pose = compose(pose, arc_offset(v[k], w[k], 0.5 * block_s))
        out[k] = pose[0]
    if anchor:
        base = invert(out[anchor])[None, :]
        out = np.array([compose(base, o)[0] for o in out])
    return out


def window_log_likelihood(
    block_log_likelihoods: Sequence[LogLikelihood], offsets: FloatArray
) -> LogLikelihood:
    """Log-likelihood of a window of blocks as a function of the first block's pose.

    Parameters
    ----------
    block_log_likelihoods : sequence of callables
        ``block_log_likelihoods[k](poses (n, 3)) -> (n,)``: the sensor model of block k (for
        example issue 6's tempered, floored heat-map likelihood at that block).
    offsets : ndarray, shape (K, 3)
        Odometry offsets from :func:`window_offsets`.

    Returns
    -------
    callable
        ``theta (n, 3) -> sum_k log L_k(theta (+) offsets[k])``.
    """
    if len(block_log_likelihoods) < 1:
        raise ValueError("block_log_likelihoods must hold >= 1 block, got 0")
    offsets = np.asarray(offsets, dtype=np.float64)
    if offsets.shape != (len(block_log_likelihoods), NDIM):
        raise ValueError(
            f"offsets must have shape ({len(block_log_likelihoods)}, 3), got {offsets.shape}"
        )
    funcs = tuple(block_log_likelihoods)

    def loglik(theta: FloatArray) -> FloatArray:
        total = np.zeros(theta.shape[0])
        for f, off in zip(funcs, offsets, strict=True):
            total += f(compose(theta, off))
        return total

    return loglik


def sensor_window_log_likelihood(
    tables: SensorTables,
    heat_maps: Sequence[HeatMap],
    speed_m_s: FloatArray,
    yaw_rate_rad_s: FloatArray,
    block_s: float,
    anchor: int = 0,
) -> LogLikelihood:
    """The window log-likelihood of issue 6's sensor model (tempered, floored, both mirrors).

    Parameters
    ----------
    tables : SensorTables
        ``localization.sensor.build_tables`` of the wall map G (its config sets the model,
        beta and z_rand; the range-only model is used by itself for slow blocks).
    heat_maps : sequence of HeatMap
        The window's blocks, consecutive (paper eq. 1).
    speed_m_s, yaw_rate_rad_s : ndarray, shape (K,)
        The blocks' odometry.
    block_s : float
        Block duration (``SonarConfig.block_s``).
    anchor : int
        Which block's pose is the parameter (see :func:`window_offsets`).
    """
    if len(heat_maps) < 1:
        raise ValueError("heat_maps must hold >= 1 block, got 0")
    measurements = [prepare_measurement(hm, tables.config) for hm in heat_maps]
    funcs = [_bind_sensor(tables, m) for m in measurements]
    return window_log_likelihood(funcs, window_offsets(speed_m_s, yaw_rate_rad_s, block_s,
                                                       anchor))


def _bind_sensor(tables: SensorTables, measurement: Any) -> LogLikelihood:
    def f(poses: FloatArray) -> FloatArray:
        return pose_log_likelihood(tables, measurement, poses)

    return f


def prior_from_tables(tables: SensorTables) -> PosePrior:
    """Uniform prior over the map's free cells (``tables.free_mask``) and every heading."""
    ny, nx = tables.shape
    res = tables.resolution_m
    x0, y0 = tables.origin_m
    return PosePrior(x0 - 0.5 * res, x0 + (nx - 0.5) * res, y0 - 0.5 * res, y0 + (ny - 0.5) * res,
                     support_mask=tables.free_mask, support_origin_m=(x0, y0),
                     support_resolution_m=res)


# ---- prior and posterior --------------------------------------------------------------
@dataclass(frozen=True)
class PosePrior:
    """Uniform prior over a box in (x, y), optionally restricted to free cells, and heading.

    Attributes
    ----------
    x_min_m, x_max_m, y_min_m, y_max_m : float
        The box (for example the mapped region).
    heading_center_rad : float or None
        None: every heading is allowed (wrapped). A value c: the sampled coordinate must lie in
        [c - pi, c + pi), one full turn, so an ensemble never drifts over many turns; the
        density on the circle is the same.
    support_mask : ndarray of bool, shape (ny, nx), optional
        Cells where the robot can be (e.g. the sensor tables' free-space mask); poses in other
        cells get prior 0. Cell ``[iy, ix]`` is centred at ``support_origin_m + (ix, iy) *
        support_resolution_m`` (the WallMap convention).
    """

    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float
    heading_center_rad: float | None = None
    support_mask: NDArray[np.bool_] | None = field(default=None, repr=False, compare=False)
    support_origin_m: tuple[float, float] = (0.0, 0.0)
    support_resolution_m: float = 1.0

    def __post_init__(self) -> None:
        for lo, hi, name in ((self.x_min_m, self.x_max_m, "x"), (self.y_min_m, self.y_max_m, "y")):
            if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
                raise ValueError(f"PosePrior {name} range must be finite with max > min, "
                                 f"got [{lo}, {hi}]")
        if self.support_mask is not None and (self.support_mask.ndim != 2
                                              or not self.support_mask.any()):
            raise ValueError("PosePrior.support_mask must be a 2-D bool array with a True cell")
        if not self.support_resolution_m > 0:
            raise ValueError(f"support_resolution_m must be > 0, got {self.support_resolution_m}")

    def with_heading_center(self, center_rad: float | None) -> PosePrior:
        """The same prior with another heading window."""
        return replace(self, heading_center_rad=center_rad)

    def log_density(self, theta: FloatArray) -> FloatArray:
        """Log prior (n,): constant inside the support, -inf outside."""
        inside = (
            (theta[:, 0] >= self.x_min_m) & (theta[:, 0] <= self.x_max_m)
            & (theta[:, 1] >= self.y_min_m) & (theta[:, 1] <= self.y_max_m)
        )
        if self.heading_center_rad is not None:
            d = theta[:, 2] - self.heading_center_rad
            inside &= (d >= -math.pi) & (d < math.pi)
        if self.support_mask is not None:
            inside &= self._in_support(theta)
        area = (self.x_max_m - self.x_min_m) * (self.y_max_m - self.y_min_m) * TWO_PI
        return np.where(inside, -math.log(area), -np.inf)

    def _in_support(self, theta: FloatArray) -> NDArray[np.bool_]:
        assert self.support_mask is not None
        ny, nx = self.support_mask.shape
        c = np.rint((theta[:, :2] - np.asarray(self.support_origin_m))
                    / self.support_resolution_m)
        ix, iy = c[:, 0], c[:, 1]
        ok = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        out = np.zeros(theta.shape[0], dtype=bool)
        out[ok] = self.support_mask[iy[ok].astype(np.int64), ix[ok].astype(np.int64)]
        return out


# ---- runs and records -----------------------------------------------------------------
def check_block_range(start: int, stop: int, n_blocks: int) -> None:
    """Raise ``ValueError`` unless ``0 <= start < stop <= n_blocks`` (blocks start..stop-1)."""
    if not 0 <= start < stop <= n_blocks:
        raise ValueError(f"blocks must be A:B with 0 <= A < B <= {n_blocks} (the run's block "
                         f"count; B exclusive), got {start}:{stop}")


def window_from_run(
    run: Run, start: int, stop: int, tables: SensorTables, anchor: int = 0
) -> tuple[LogLikelihood, FloatArray]:
    """Window log-likelihood of blocks ``start..stop-1`` of a run, and the anchor's true pose.

    Heat maps come from :func:`mapping.heatmap.heatmap_of_run` (paper eq. 1, with the bank
    the sensor model reads: :func:`localization.sensor.heatmap_run`), odometry from
    the run; the parameter is the pose of block ``start + anchor``, whose tracked pose (3,)
    is returned too (NaN where untracked).
    """
    check_block_range(start, stop, run.n_blocks)
    heard = heatmap_run(run, tables.config)     # the bank the sensor model reads
    heat_maps = [heatmap_of_run(heard, k) for k in range(start, stop)]
    loglik = sensor_window_log_likelihood(
        tables, heat_maps, run.speed_m_s[start:stop], run.yaw_rate_rad_s[start:stop],
        run.config.block_s, anchor)
    return loglik, np.asarray(run.pose[start + anchor], dtype=np.float64)
