"""Test inputs for the localization tests, independent of the simulation pipeline.

A wall map made by rasterizing known wall segments, and heat maps synthesized from the
same segments by geometry alone: each wall whose perpendicular foot lies on the segment
returns a specular echo at its perpendicular distance d and bearing theta_n, spread over
direction the way a Doppler bank spreads it (Gaussian in cos(theta), eq. 1) and over range
by the chip length; amplitude 1/d; plus a noise floor.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from localization.motion import predict_mean
from localization.sensor import SensorConfig, SensorTables, build_tables
from mapping.angles import wrap_angle
from mapping.heatmap import HeatMap
from mapping.wallmap import WallMap

FloatArray = NDArray[np.float64]

#: A 4 m x 3 m room with its top-right corner cut at 45 deg and a stub wall hanging from
#: the top: no symmetry.
ASYMMETRIC_ROOM = np.array([
    [[0.0, 0.0], [4.0, 0.0]], [[4.0, 0.0], [4.0, 1.6]], [[4.0, 1.6], [2.6, 3.0]],
    [[2.6, 3.0], [0.0, 3.0]], [[0.0, 3.0], [0.0, 0.0]], [[1.0, 3.0], [1.0, 2.4]],
])

#: A 6 m x 1.6 m corridor: symmetric under 180 deg rotation and both mirror axes.
CORRIDOR = np.array([
    [[0.0, 0.0], [6.0, 0.0]], [[6.0, 0.0], [6.0, 1.6]], [[6.0, 1.6], [0.0, 1.6]],
    [[0.0, 1.6], [0.0, 0.0]],
])


def rasterize(segments: FloatArray, resolution_m: float = 0.05, margin_m: float = 0.5,
              width_cells: float = 0.7) -> WallMap:
    """WallMap with a Gaussian ridge (std ``width_cells``) along every segment."""
    lo = segments.reshape(-1, 2).min(axis=0) - margin_m
    hi = segments.reshape(-1, 2).max(axis=0) + margin_m
    nx, ny = (np.ceil((hi - lo) / resolution_m).astype(int) + 1)
    xs = lo[0] + resolution_m * np.arange(nx)
    ys = lo[1] + resolution_m * np.arange(ny)
    px, py = np.meshgrid(xs, ys)
    d = np.full(px.shape, np.inf)
    for (a, b) in segments:
        ab = b - a
        t = np.clip(((px - a[0]) * ab[0] + (py - a[1]) * ab[1]) / (ab @ ab), 0, 1)
        d = np.minimum(d, np.hypot(px - a[0] - t * ab[0], py - a[1] - t * ab[1]))
    G = np.exp(-0.5 * (d / (width_cells * resolution_m)) ** 2)
    return WallMap(G=G, origin_m=(float(lo[0]), float(lo[1])), resolution_m=resolution_m)


def synthetic_heatmap(
    segments: FloatArray, pose: FloatArray, speed_m_s: float, rng: np.random.Generator,
    noise: float = 0.02, n_dirs: int = 30, n_ranges: int = 2000,
    range_step_m: float = 340.0 / 80_000.0, observable_speed_m_s: float = 0.03,
) -> HeatMap:
    """Heat map (n_dirs, n_ranges) of specular echoes off ``segments`` seen from ``pose``."""
    angles = np.pi * np.arange(n_dirs) / (n_dirs - 1)
    ranges = np.asarray(range_step_m * np.arange(n_ranges), dtype=np.float64)
    observable = abs(speed_m_s) >= observable_speed_m_s
    sigma_cos = min(0.12 * 0.2 / max(abs(speed_m_s), 1e-3), 10.0)
    H = np.zeros((n_dirs, n_ranges))
    p = np.asarray(pose[:2], dtype=np.float64)
    for a, b in segments:
        ab = b - a
        t = float((p - a) @ ab / (ab @ ab))
        if not 0.0 <= t <= 1.0:
            continue
        foot = a + t * ab
        d = float(np.hypot(*(foot - p)))
        bearing = abs(float(wrap_angle(math.atan2(foot[1] - p[1], foot[0] - p[0]) - pose[2])))
        if speed_m_s < 0:   # angles from the direction of travel, heading + pi
            bearing = math.pi - bearing
        row = np.exp(-0.5 * ((np.cos(angles) - math.cos(bearing)) / sigma_cos) ** 2)
        if not observable:
            row = np.ones(n_dirs)
        col = np.exp(-0.5 * ((ranges - d) / 0.012) ** 2)
        H += (1.0 / max(d, 0.1)) * row[:, None] * col[None, :]
    H += noise * np.abs(rng.standard_normal(H.shape)) * (H.max() if H.max() > 0 else 1.0)
    if not observable:
        H = np.repeat(H.max(axis=0, keepdims=True), n_dirs, axis=0)
    return HeatMap(H=H, angles_rad=angles, ranges_m=ranges, speed_m_s=float(speed_m_s),
                   direction_observable=observable)


def trajectory(start: FloatArray, odometry: list[tuple[float, float]], dt_s: float
               ) -> FloatArray:
    """Poses (n + 1, 3) dead-reckoned exactly from ``start`` with (speed, yaw rate) steps."""
    poses = [np.asarray(start, dtype=np.float64)]
    for v, w in odometry:
        poses.append(predict_mean(poses[-1], v, w, dt_s))
    return np.array(poses)


def asymmetric_tables() -> SensorTables:
    """Sensor tables of the rasterized ASYMMETRIC_ROOM (the filters' shared test map)."""
    return build_tables(rasterize(ASYMMETRIC_ROOM), SensorConfig(max_range_m=4.5))


def synthetic_track(segments: FloatArray, start: FloatArray,
                    odometry: list[tuple[float, float]], dt_s: float, seed: int,
                    noise: float = 0.2) -> tuple[FloatArray, list[HeatMap]]:
    """True poses dead-reckoned from ``start`` and a noisy synthetic heat map at each."""
    truth = trajectory(start, odometry, dt_s)
    rng = np.random.default_rng(seed)
    return truth, [synthetic_heatmap(segments, p, noise, rng) for p in truth]


def odometry_step(odometry: list[tuple[float, float]], dt_s: float, k: int
                  ) -> tuple[float, float, float]:
    """(speed, yaw rate, dt) that led to pose ``k`` of a :func:`trajectory` (k = 0: at rest
    on the first leg's speed, no time elapsed)."""
    return (*odometry[k - 1], dt_s) if k > 0 else (odometry[0][0], 0.0, 0.0)
