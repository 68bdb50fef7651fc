"""Checking a forward model against a heat map: peak matching and map correlation."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mapping.forward._echoes import Echoes
from mapping.heatmap import HeatMap

BoolArray = NDArray[np.bool_]


def echo_cells(echoes: Echoes, hm: HeatMap) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Heat-map cells (n_theta, n_tau) nearest to each echo's angle and range (range wraps)."""
    p = hm.ranges_m.size
    step = float(hm.ranges_m[1] - hm.ranges_m[0])
    col = np.rint(echoes.range_m / step).astype(np.int64) % p
    row = np.abs(hm.angles_rad[None, :] - echoes.angle_rad[:, None]).argmin(axis=1)
    return row.astype(np.int64), col


def local_maxima(hm: HeatMap) -> BoolArray:
    """Cells not smaller than any of their 8 neighbours (range circular; the angle axis is
    mirrored at 0 and pi, where the folded map is symmetric)."""
    H = hm.H
    padded = np.concatenate([H[1:2], H, H[-2:-1]], axis=0)
    padded = np.concatenate([padded[:, -1:], padded, padded[:, :1]], axis=1)
    peak = np.ones(H.shape, dtype=bool)
    n, p = H.shape
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                peak &= H >= padded[1 + dr: 1 + dr + n, 1 + dc: 1 + dc + p]
    return peak


def match_echoes(
    echoes: Echoes, hm: HeatMap, *, range_bins: int = 1, angle_bins: int = 1,
    resolution_bins: int = 4, cos_tolerance: float = 0.0,
) -> BoolArray:
    """For each echo: is there a local maximum of ``hm`` within ``range_bins`` lags and
    ``angle_bins`` rows of the cell it should land in?

    Echoes closer than ``resolution_bins`` lags (one chip for Table 1: the range
    resolution) and ``angle_bins`` rows make one peak together (e.g. a path and its reverse,
    a few mm apart by retardation): each is matched by a maximum anywhere within
    ``range_bins`` of that group's span. Rows whose ``cos theta`` is within
    ``cos_tolerance`` of the echo's Doppler cosine count too (near 0 and pi one row is a
    tiny step in Doppler, below what a block resolves). Without observable direction any
    row counts.
    """
    peaks = local_maxima(hm)
    rows, cols = echo_cells(echoes, hm)
    n, p = hm.H.shape
    out = np.zeros(rows.size, dtype=bool)
    for i, (r, c) in enumerate(zip(rows, cols, strict=True)):
        dc = (cols - c + p // 2) % p - p // 2
        group = (np.abs(dc) <= resolution_bins) & (np.abs(rows - r) <= angle_bins)
        lo_r, hi_r = int(rows[group].min()), int(rows[group].max())
        lo, hi = (0, n) if not hm.direction_observable else (
            max(lo_r - angle_bins, 0), min(hi_r + angle_bins + 1, n))
        cs = np.arange(c + dc[group].min() - range_bins, c + dc[group].max() + range_bins + 1) % p
        ok_rows = np.zeros(n, dtype=bool)
        ok_rows[lo:hi] = True
        ok_rows |= np.abs(np.cos(hm.angles_rad) - np.cos(echoes.angle_rad[i])) <= cos_tolerance
        out[i] = bool(peaks[ok_rows][:, cs].any())
    return out


def heatmap_correlation(a: HeatMap, b: HeatMap, max_range_m: float | None = None) -> float:
    """Pearson correlation of two heat maps on the same axes (ranges <= ``max_range_m``)."""
    if a.H.shape != b.H.shape:
        raise ValueError(f"heat maps must have the same shape, got {a.H.shape} and {b.H.shape}")
    keep = slice(None) if max_range_m is None else a.ranges_m <= max_range_m
    x, y = a.H[:, keep].ravel(), b.H[:, keep].ravel()
    x, y = x - x.mean(), y - y.mean()
    den = float(np.sqrt(np.dot(x, x) * np.dot(y, y)))
    return float(np.dot(x, y) / den) if den > 0 else 0.0
