"""Sensor model: the likelihood of a live heat map given a pose and the wall map G.

At a pose ``(x, y, heading)`` the map predicts what the sonar should see by sampling G on a
polar grid around the pose: ``n_angles`` directions ``phi_j = 2 pi j / n_angles`` measured
from the heading, over the full circle, and range bins ``r_k``. This inverts the paper's
back-projection (Sec. 2.2, eqs. 2-4: a heat-map pixel at direction ``n_theta`` and lag
``n_tau`` lands on the map cell at that bearing and range ``c n_tau / (2 fs)``).

The measured heat map (eq. 1) only knows ``|phi|`` in [0, pi]: the Doppler factor depends on
``cos(theta)``, so the left and right mirror directions are the same row. The measurement is
therefore *unfolded* onto the same full-circle grid, ``M[k, j] = H(|phi_j|, r_k)`` (mirror
sides equal), and compared with the prediction by the Pearson correlation ``rho`` over all
polar bins. Because ``M`` is mirror symmetric, this equals correlating the folded prediction
``P(+phi) + P(-phi)`` with ``H``.

Two models share the tables:

``correlation``  the full polar correlation above;
``range``        range-only: the measured range profile (max over directions) against the
                 prediction summed over all directions at each range. The sum (not a max)
                 is deliberate: a ring of radius r around the pose grazes a wall at its
                 perpendicular distance, where the ring runs along the wall, so the ring sum
                 peaks at the specular ranges the sonar actually hears. The range model does
                 not depend on the heading at all (the particle filter evaluates it at
                 heading bin 0), so a stationary robot never invents a bearing.

The correlation becomes a likelihood by tempering and flooring (AMCL's ``z_rand``)::

    p(z | x) = (1 - z_rand) exp(beta (rho - 1)) + z_rand

Lookup tables make one particle a gather and a dot product: G (lightly blurred, padded by
the maximum range) is flattened, the direction cosines of every (heading bin, polar angle)
and the ranges in cells are tabulated, and the sample sums the correlation's denominator
needs are precomputed per cell; a particle then costs one nearest-cell gather and one
multiply-add per kept measurement entry. (A table of precomputed flat offsets per heading
bin and sub-cell phase was tried first: 36 MB, and on this shared machine reading its rows
cost more than computing the offsets.) Exhaustive scoring of every heading at a cell
is a circular cross-correlation along the angle axis, done with FFTs
(:func:`score_cells_all_headings`); it is exactly the particle score at the cell centre and
heading ``2 pi m / n_angles``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from localization.sensor import _kernels as _k
from localization.sensor._config import SensorConfig
from localization.sensor._echo import score_echo_poses
from localization.sensor._measurement import (
    Measurement,
)
from localization.sensor._tables import SensorTables

FloatArray = NDArray[np.float64]

#: Log-likelihood given to a pose outside the map (below the z_rand floor).
OFF_MAP_PENALTY = 10.0


# ---- scoring -------------------------------------------------------------------------------
def _index(tables: SensorTables, poses: FloatArray) -> _k._Particles:
    """Padded flat index of each pose's nearest cell, its offset (ux, uy) from that cell's
    centre in cells, its heading bin and its map cell (-1 off the map)."""
    cfg = tables.config
    c = (poses[:, :2] - np.asarray(tables.origin_m)) / tables.resolution_m
    near = np.floor(c + 0.5)
    u = c - near
    u = np.where(np.abs(u) < 1e-9, 0.0, u)       # cell centres exactly
    ix, iy = near[:, 0].astype(np.int64), near[:, 1].astype(np.int64)
    iy0, iy1, ix0, ix1 = tables.active
    on = (ix >= ix0) & (ix < ix1) & (iy >= iy0) & (iy < iy1)
    hb = np.rint(poses[:, 2] * cfg.n_headings / (2 * np.pi)).astype(np.int64) % cfg.n_headings
    cell = np.where(on, iy * tables.shape[1] + ix, -1).astype(np.int64)
    base = np.where(on, (iy + tables.pad) * tables.nx_pad + ix + tables.pad, 0)
    return _k._Particles(base=base.astype(np.int64), ux=np.ascontiguousarray(u[:, 0]),
                         uy=np.ascontiguousarray(u[:, 1]), hb=hb, cell=cell)


def _check(poses: FloatArray) -> FloatArray:
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must have shape (n, 3), got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise ValueError("poses contain NaN or inf")
    return poses


def score_poses(tables: SensorTables, measurement: Measurement, poses: FloatArray) -> FloatArray:
    """Correlation ``rho`` in [-1, 1] of the measurement with G at each pose (n, 3).

    NaN marks a pose off the map. Correlation model: one pose costs one gather and one
    multiply-add per kept measurement entry (a serial numba loop over poses); the sample sums
    in the denominator are the pose's cell-centre values (heading-invariant up to the
    polar sampling). Range model: a dot product with the cell's ring profile; it does not
    depend on the heading at all.
    """
    poses = _check(poses)
    if measurement.model == "echo":
        return score_echo_poses(tables, measurement, poses)
    particles = _index(tables, poses)
    if measurement.model == "range":
        return _k.score_range(tables.ring, particles.cell, measurement.dense)
    return _k.score(tables._kernel, particles, measurement.idx, measurement.val,
                    measurement.m_mean, measurement.m_norm)


def log_likelihood(rho: FloatArray, config: SensorConfig, rho_ref: float = 1.0) -> FloatArray:
    """Tempered, floored log-likelihood ``log((1 - z) exp(beta (rho - rho_ref)) + z)``.

    Parameters
    ----------
    rho : ndarray
        Correlations from :func:`score_poses` (NaN = off the map).
    config : SensorConfig
        ``beta`` and ``z_rand``.
    rho_ref : float
        Correlation that gets the full likelihood 1. A particle filter passes the best
        correlation in its set, so the floor bounds the weight ratio one block can cause
        to ``1 / z_rand``; 1.0 (the perfect match) gives an absolute scale.

    Returns
    -------
    ndarray
        Log-likelihoods, the shape of ``rho``; a NaN correlation (off the map) maps to
        ``log(z_rand) - OFF_MAP_PENALTY``.
    """
    rho = np.asarray(rho, dtype=np.float64)
    z = config.z_rand
    ll = np.logaddexp(np.log1p(-z) + config.beta * (np.nan_to_num(rho, nan=-1.0) - rho_ref),
                      math.log(z))
    return np.where(np.isnan(rho), math.log(z) - OFF_MAP_PENALTY, ll)


def pose_log_likelihood(tables: SensorTables, measurement: Measurement, poses: FloatArray,
                        floor: bool = False) -> FloatArray:
    """``log p(heat map | pose, G)`` up to a constant, for each pose (n, 3).

    Without ``floor`` this is ``beta * rho`` (a smooth log-likelihood for MCMC; off-map
    poses get ``-inf``); with it, :func:`log_likelihood` relative to the best pose given.
    """
    rho = score_poses(tables, measurement, poses)
    if floor:
        ref = float(np.nanmax(rho)) if np.isfinite(rho).any() else 1.0
        return log_likelihood(rho, tables.config, ref)
    return np.where(np.isnan(rho), -np.inf, tables.config.beta * np.nan_to_num(rho))


def polar_prediction(tables: SensorTables, pose: FloatArray) -> FloatArray:
    """G sampled around one pose (3,): shape (n_r, n_angles), angles ``config.angles_rad``."""
    poses = _check(np.asarray(pose, dtype=np.float64).reshape(1, 3))
    base, ux, uy, hb, cell = _index(tables, poses)
    if cell[0] < 0:
        raise ValueError(f"pose {pose} is off the map")
    r = tables.r_cells[:, None]
    dx = np.floor(r * tables.cos_tab[hb[0]][None, :] + (ux[0] + 0.5))
    dy = np.floor(r * tables.sin_tab[hb[0]][None, :] + (uy[0] + 0.5))
    flat = base[0] + (dy * tables.nx_pad + dx).astype(np.int64)
    return tables.g[flat].astype(np.float64)


# ---- exhaustive scoring ---------------------------------------------------------------------
def cell_polar_samples(tables: SensorTables, cells: NDArray[np.int64]) -> NDArray[np.float32]:
    """Polar samples at heading 0 around cell centres ``cells`` (n, 2) as (iy, ix).

    Returns shape (n, n_r, n_angles).
    """
    base = (cells[:, 0] + tables.pad) * tables.nx_pad + cells[:, 1] + tables.pad
    out = tables.g[base[:, None] + tables.offsets0[None, :]]
    return out.reshape(cells.shape[0], tables.n_r, tables.config.n_angles)


def _range_scores_numpy(ring: NDArray[np.float32], cell: NDArray[np.int64],
                        m0: FloatArray) -> FloatArray:
    """Range-model ``rho`` at the cells ``cell`` (< 0: nan), in numpy.

    Kept in production for :func:`score_cells_all_headings` (numpy and FFTs throughout):
    centring each ring profile first gives the values it has always returned to the last
    bit, which the range kernel (sums and sums of squares) need not. Not the kernel's test
    twin; that is a copy of this code in ``tests/localization/sensor/naive.py``.
    """
    out = np.full(cell.shape[0], np.nan)
    ok = cell >= 0
    p = ring[cell[ok]].astype(np.float64)
    pc = p - p.mean(axis=1, keepdims=True)
    norm = np.sqrt((pc**2).sum(axis=1))
    out[ok] = np.where(norm > 1e-9, (pc @ m0) / np.maximum(norm, 1e-9), 0.0)
    return out


def score_cells_all_headings(
    tables: SensorTables, measurement: Measurement, cells: NDArray[np.int64],
    chunk: int = 512,
) -> FloatArray:
    """``rho`` at every cell centre (n, 2 as iy, ix) and every heading ``2 pi m / n_angles``.

    The correlation model is a circular cross-correlation along the angle axis (FFT) and
    equals :func:`score_poses` at those poses; the range model does not depend on the
    heading (all columns equal). Returns (n, n_angles).
    """
    cfg = tables.config
    cells = np.asarray(cells, dtype=np.int64)
    flat = cells[:, 0] * tables.shape[1] + cells[:, 1]
    if measurement.model == "echo":
        # no circular structure to exploit: score every (cell, heading) pose directly
        xy = np.asarray(tables.origin_m) + cells[:, ::-1] * tables.resolution_m
        h = 2.0 * np.pi * np.arange(cfg.n_angles) / cfg.n_angles
        poses = np.column_stack([np.repeat(xy, cfg.n_angles, axis=0),
                                 np.tile(h, cells.shape[0])])
        return score_echo_poses(tables, measurement, poses).reshape(-1, cfg.n_angles)
    if measurement.model == "range":
        rho = _range_scores_numpy(tables.ring, flat, measurement.dense)
        return np.repeat(rho[:, None], cfg.n_angles, axis=1)
    out = np.empty((cells.shape[0], cfg.n_angles))
    fm = np.conj(np.fft.rfft(measurement.dense.reshape(tables.n_r, cfg.n_angles), axis=1))
    n = tables.n_samples
    for s in range(0, cells.shape[0], chunk):
        q = cell_polar_samples(tables, cells[s:s + chunk]).astype(np.float64)
        num = np.fft.irfft((np.fft.rfft(q, axis=2) * fm[None]).sum(axis=1), n=cfg.n_angles,
                           axis=1)
        c = flat[s:s + chunk]
        s1, s2 = tables.s1[c], tables.s2[c]
        var = s2 - s1**2 / n
        den = measurement.m_norm * np.sqrt(np.maximum(var, 1e-18))
        out[s:s + chunk] = np.where(var[:, None] > 1e-18,
                                    (num - measurement.m_mean * s1[:, None]) / den[:, None], 0.0)
    return out
