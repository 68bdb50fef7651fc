"""Pose logs and blocks: a sonar stream's blocks and their odometry, and back (issue 3, item 5).

A stream already at the sonar rate and period-aligned (sample 0 emitted-aligned with sample 0
of the transmitted sequence, the time convention of :mod:`mapping.signal`) is cut into blocks
``k B .. (k + 1) B - 1``; block ``k`` starts at ``t = k B / fs`` unless the caller gives the
start times (the raw import does: block starts on the recording's clock). For each block the
run file needs (see :mod:`mapping.run`):

- ``pose``: the logged pose interpolated to the block midpoint (start + block_s / 2)
  (x and y linearly, heading along the shorter arc between log rows);
- ``speed_m_s``: the logged speed (linear between rows) averaged over the block;
- ``yaw_rate_rad_s``: the heading change across the block divided by its duration.

Where the log does not cover the whole block the average and the heading change are taken
over the part it covers; a block whose midpoint is outside the log is an error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: Column names of a pose log, in order.
POSE_COLUMNS = ("t_s", "x_m", "y_m", "heading_rad", "speed_m_s")


@dataclass(frozen=True)
class PoseLog:
    """A robot's pose log: rows at strictly increasing times ``t_s`` (all arrays (n,))."""

    t_s: FloatArray
    x_m: FloatArray
    y_m: FloatArray
    heading_rad: FloatArray
    speed_m_s: FloatArray

    def __post_init__(self) -> None:
        n = self.t_s.shape
        if len(n) != 1 or n[0] < 2:
            raise ValueError(f"t_s must be 1-D with >= 2 rows, got shape {n}")
        for name in POSE_COLUMNS:
            arr = getattr(self, name)
            if arr.shape != n:
                raise ValueError(f"{name} must have shape {n}, got {arr.shape}")
            bad = ~np.isfinite(arr)
            if bad.any():
                i = int(np.argmax(bad))
                raise ValueError(f"{name} must be finite; row {i} is {arr[i]}")
        step = np.diff(self.t_s)
        if np.any(step <= 0):
            i = int(np.argmax(step <= 0)) + 1
            raise ValueError(
                f"t_s must increase strictly; row {i} ({self.t_s[i]}) follows {self.t_s[i - 1]}"
            )


@dataclass(frozen=True)
class BlockOdometry:
    """Per-block values of a run: start times, midpoint poses, mean speed and yaw rate."""

    t_s: FloatArray
    pose: FloatArray
    speed_m_s: FloatArray
    yaw_rate_rad_s: FloatArray


def split_blocks(samples: NDArray[np.floating], block_samples: int) -> NDArray[np.float32]:
    """Cut a 1-D sample stream into whole blocks (n_blocks, B); a trailing partial block is
    dropped.

    Raises
    ------
    ValueError
        If ``samples`` is not 1-D and finite, ``block_samples < 1`` or fewer than one block.
    """
    x = np.asarray(samples)
    if block_samples < 1:
        raise ValueError(f"block_samples must be >= 1, got {block_samples}")
    if x.ndim != 1:
        raise ValueError(f"samples must be a 1-D (mono) stream, got shape {x.shape}")
    n_blocks = x.size // block_samples
    if n_blocks < 1:
        raise ValueError(
            f"samples holds {x.size} samples, fewer than one block of {block_samples}"
        )
    if not np.all(np.isfinite(x)):
        raise ValueError("samples contains NaN or inf")
    return x[: n_blocks * block_samples].astype(np.float32).reshape(n_blocks, block_samples)


def join_blocks(blocks: NDArray[np.floating]) -> NDArray[np.float32]:
    """Inverse of :func:`split_blocks`: the blocks (n_blocks, B) as one float32 stream."""
    b = np.asarray(blocks)
    if b.ndim != 2:
        raise ValueError(f"blocks must have shape (n_blocks, B), got {b.shape}")
    return b.astype(np.float32).reshape(-1)


def heading_at(log: PoseLog, t_s: FloatArray) -> FloatArray:
    """Unwrapped heading at times ``t_s`` (clamped to the log), interpolated on the circle:
    between two rows along the shorter arc."""
    return np.interp(t_s, log.t_s, np.unwrap(log.heading_rad))


def poses_at(log: PoseLog, t_s: ArrayLike) -> FloatArray:
    """Poses (n, 3) ``[x, y, heading]`` at times inside the log, heading wrapped to (-pi, pi].

    Raises
    ------
    ValueError
        If a time lies outside ``[log.t_s[0], log.t_s[-1]]``.
    """
    t = np.asarray(t_s, dtype=np.float64)
    outside = (t < log.t_s[0]) | (t > log.t_s[-1])
    if outside.any():
        i = int(np.argmax(outside))
        raise ValueError(
            f"t_s[{i}] = {t[i]:.6g} s is outside the pose log's time span "
            f"[{log.t_s[0]:.6g}, {log.t_s[-1]:.6g}] s"
        )
    h = heading_at(log, t)
    wrapped = np.pi - np.mod(np.pi - h, 2.0 * np.pi)
    return np.column_stack([np.interp(t, log.t_s, log.x_m), np.interp(t, log.t_s, log.y_m),
                            wrapped])


def _speed_integral(log: PoseLog, t: FloatArray) -> FloatArray:
    """Integral of the piecewise-linear speed from ``log.t_s[0]`` to ``t`` (t inside the log)."""
    ts, v = log.t_s, log.speed_m_s
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(ts))])
    k = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, ts.size - 2)
    dt = t - ts[k]
    slope = (v[k + 1] - v[k]) / (ts[k + 1] - ts[k])
    return cum[k] + v[k] * dt + 0.5 * slope * dt * dt


def block_odometry(log: PoseLog, n_blocks: int, block_s: float,
                   start_s: ArrayLike | None = None) -> BlockOdometry:
    """Per-block run values from a pose log (see the module docstring).

    Parameters
    ----------
    log : PoseLog
        The pose log.
    n_blocks : int
        Number of blocks, >= 1.
    block_s : float
        Block duration in seconds on the log's clock, > 0 (``SonarConfig.block_s``, or that
        times ``1 + clock_offset_ppm * 1e-6`` for a raw recording).
    start_s : array_like, shape (n_blocks,), optional
        Block start times on the log's clock, finite; default ``k * block_s`` (block k spans
        ``[k block_s, (k + 1) block_s)``).

    Returns
    -------
    BlockOdometry
        ``t_s`` block starts, ``pose`` at block midpoints, block-mean ``speed_m_s`` and
        ``yaw_rate_rad_s``.

    Raises
    ------
    ValueError
        If a block midpoint lies outside the log, naming the block, or ``start_s`` has the
        wrong shape or is not finite.
    """
    if n_blocks < 1:
        raise ValueError(f"n_blocks must be >= 1, got {n_blocks}")
    if not block_s > 0:
        raise ValueError(f"block_s must be > 0, got {block_s}")
    if start_s is None:
        t0 = np.arange(n_blocks, dtype=np.float64) * block_s
    else:
        t0 = np.asarray(start_s, dtype=np.float64)
        if t0.shape != (n_blocks,) or not np.all(np.isfinite(t0)):
            raise ValueError(f"start_s must be {n_blocks} finite times, got shape {t0.shape}")
    mid = t0 + 0.5 * block_s
    try:
        pose = poses_at(log, mid)
    except ValueError as exc:
        raise ValueError(f"block midpoints must lie inside the pose log: {exc}") from None
    a = np.clip(t0, log.t_s[0], log.t_s[-1])
    b = np.clip(t0 + block_s, log.t_s[0], log.t_s[-1])
    span = b - a  # > 0: the midpoint is inside the log
    speed = (_speed_integral(log, b) - _speed_integral(log, a)) / span
    yaw = (heading_at(log, b) - heading_at(log, a)) / span
    return BlockOdometry(t_s=t0, pose=pose, speed_m_s=speed, yaw_rate_rad_s=yaw)


def pose_log_from_blocks(t_s: ArrayLike, pose: ArrayLike, speed_m_s: ArrayLike,
                         block_s: float) -> PoseLog:
    """A pose log with one row per tracked block, at its midpoint (the export direction).

    Rows whose pose is NaN (untracked blocks) are left out.
    """
    pose = np.asarray(pose, dtype=np.float64)
    keep = ~np.isnan(pose).any(axis=1)
    if keep.sum() < 2:
        raise ValueError("pose must have >= 2 tracked (non-NaN) rows to export a pose log")
    p = pose[keep]
    return PoseLog(
        t_s=np.asarray(t_s, dtype=np.float64)[keep] + 0.5 * block_s,
        x_m=p[:, 0].copy(), y_m=p[:, 1].copy(), heading_rad=p[:, 2].copy(),
        speed_m_s=np.asarray(speed_m_s, dtype=np.float64)[keep],
    )
