"""Ideal polar heat maps from ground-truth wall geometry (test truth for the map code).

A planar wall seen from pose p echoes from the foot of the perpendicular (specular point) at
one-way range d and bearing beta; the Doppler heat map only knows |beta - heading|. The ideal
heat map puts a Gaussian peak at (|angle|, d) with a stated angular and range spread.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mapping.heatmap import HeatMap


def specular_points(pose: NDArray[np.float64], segments: NDArray[np.float64]) -> list[tuple]:
    """(range_m, bearing_rad) of every wall segment's specular point seen from ``pose``."""
    p = np.asarray(pose[:2])
    out = []
    for a, b in np.asarray(segments, dtype=np.float64):
        t = np.dot(p - a, b - a) / np.dot(b - a, b - a)
        if 0.0 <= t <= 1.0:
            q = a + t * (b - a)
            d = q - p
            out.append((float(np.hypot(*d)), float(np.arctan2(d[1], d[0]))))
    return out


def ideal_heatmap(
    pose: NDArray[np.float64], segments: NDArray[np.float64], n_dirs: int = 30,
    n_samples: int = 2048, dr: float = 340.0 / 80000.0, sigma_rad: float = 0.08,
    sigma_m: float = 0.008, amplitude_at_1m: float = 1.0, sigma_cos: float | None = None,
    points: NDArray[np.float64] | None = None, kappa: float | None = None,
) -> HeatMap:
    """Noise-free heat map of specular echoes (+-mirror inherent: only |angle| is kept).

    ``sigma_cos`` spreads the echo uniformly in cos(angle) (the Doppler resolution) instead of
    ``sigma_rad`` in angle, ``kappa`` gives the Doppler response ``|sinc(kappa dcos)|``
    (kappa = 2 v T fc / c carrier cycles of drift); ``points`` (n, 2) are retro-reflectors
    (corners) seen from anywhere.
    """
    angles = np.pi * np.arange(n_dirs) / (n_dirs - 1)
    ranges = dr * np.arange(n_samples, dtype=np.float64)
    H = np.zeros((n_dirs, n_samples))
    echoes = specular_points(pose, segments)
    for q in ([] if points is None else np.asarray(points)):
        d = q - pose[:2]
        echoes.append((float(np.hypot(*d)), float(np.arctan2(d[1], d[0]))))
    for r, beta in echoes:
        a = abs((beta - pose[2] + np.pi) % (2 * np.pi) - np.pi)
        amp = amplitude_at_1m / max(r, 0.1)
        if kappa is not None:
            ang = np.log(np.abs(np.sinc(kappa * (np.cos(angles[:, None]) - np.cos(a)))) + 1e-300)
        elif sigma_cos is None:
            ang = -0.5 * ((angles[:, None] - a) / sigma_rad) ** 2
        else:
            ang = -0.5 * ((np.cos(angles[:, None]) - np.cos(a)) / sigma_cos) ** 2
        H += amp * np.exp(ang - 0.5 * ((ranges[None, :] - r) / sigma_m) ** 2)
    return HeatMap(H=H, angles_rad=angles, ranges_m=ranges, speed_m_s=0.1,
                   direction_observable=True)
