"""Diagnostics of the pose posterior: samples against grids, HPD regions, cloud calibration.

Summaries and checks used by :mod:`localization.posterior`: sample moments and intervals with
the heading unwrapped, highest-posterior-density thresholds, the comparison of a sampler with a
grid posterior on a shared histogram (Hellinger, KL, HPD coverage) and the calibration of a
particle filter's cloud against the posterior.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.posterior._grid import GridPosterior, _step
from localization.posterior._records import GridComparison, PosteriorResult
from localization.posterior._window import (
    NDIM,
    TWO_PI,
    FloatArray,
    _unwrap_about,
)
from mapping.angles import mean_resultant, pose_difference


def _bin_index(values: FloatArray, axis: FloatArray, n_bins: int) -> NDArray[np.int64]:
    """Bin of each value on ``n_bins`` equal bins over the axis' cell edges; -1 outside."""
    d = _step(axis)
    lo, hi = axis[0] - 0.5 * d, axis[-1] + 0.5 * d
    idx = np.floor((values - lo) / (hi - lo) * n_bins).astype(np.int64)
    return np.where((idx >= 0) & (idx < n_bins), idx, -1)


def compare_with_grid(
    samples: FloatArray, grid: GridPosterior, n_bins: int, n_effective: float,
    rng: np.random.Generator,
) -> GridComparison:
    """Compare samples (heading in the grid's own unwrapping) with a grid posterior.

    Both are binned on a shared ``n_bins``^3 histogram over the grid's box; see
    :class:`GridComparison` for the numbers returned.
    """
    if grid.periodic:
        h0 = grid.heading_rad[0] - 0.5 * _step(grid.heading_rad)
        samples = samples.copy()
        samples[:, 2] = h0 + np.mod(samples[:, 2] - h0, TWO_PI)
    axes = (grid.x_m, grid.y_m, grid.heading_rad)
    cell = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    p = _histogram(cell, axes, n_bins, grid.prob.ravel())
    q_counts = _histogram(samples, axes, n_bins, np.ones(samples.shape[0]))
    outside = 1.0 - q_counts.sum() / samples.shape[0]
    q = q_counts / samples.shape[0]
    n_iid = max(1, int(round(n_effective)))
    q_iid = rng.multinomial(n_iid, p / p.sum()) / n_iid
    q_smooth = (q_counts + 0.5) / (q_counts.sum() + 0.5 * q_counts.size)
    nz = p > 0
    order = np.argsort(-q, kind="stable")
    cum = np.cumsum(q[order])
    cover = [float(p[order[: int(np.searchsorted(cum, lev * cum[-1]) + 1)]].sum())
             for lev in (0.68, 0.95)]
    return GridComparison(
        hellinger=_hellinger(p, q),
        hellinger_iid=_hellinger(p, q_iid),
        kl_grid_to_samples=float(np.sum(p[nz] * np.log(p[nz] / q_smooth[nz]))),
        coverage68=cover[0],
        coverage95=cover[1],
        outside=float(outside),
        n_effective=float(n_effective),
    )


def _histogram(pts: FloatArray, axes: tuple[FloatArray, ...], n_bins: int,
               weights: FloatArray) -> FloatArray:
    idx = [_bin_index(pts[:, i], axes[i], n_bins) for i in range(3)]
    ok = (idx[0] >= 0) & (idx[1] >= 0) & (idx[2] >= 0)
    flat = (idx[0][ok] * n_bins + idx[1][ok]) * n_bins + idx[2][ok]
    return np.bincount(flat, weights=weights[ok], minlength=n_bins**3).astype(np.float64)


def _hellinger(p: FloatArray, q: FloatArray) -> float:
    bc = float(np.sum(np.sqrt(p / p.sum() * np.maximum(q, 0) / max(q.sum(), 1e-300))))
    return math.sqrt(max(0.0, 1.0 - bc))


def summarize_samples(samples: FloatArray) -> tuple[FloatArray, FloatArray, float, FloatArray,
                                                    FloatArray]:
    """Mean (x, y, circular mean heading), covariance, R and 68/95 % intervals of samples.

    The heading is unwrapped about its circular mean before the covariance and intervals.
    """
    c, r = mean_resultant(samples[:, 2])
    un = _unwrap_about(samples, c)
    un[:, 2] = np.where(un[:, 2] < c - math.pi, un[:, 2] + TWO_PI, un[:, 2])
    mean = np.array([un[:, 0].mean(), un[:, 1].mean(), c])
    cov = np.cov(un, rowvar=False)
    i68 = np.quantile(un, [0.16, 0.84], axis=0).T
    i95 = np.quantile(un, [0.025, 0.975], axis=0).T
    return mean, np.atleast_2d(cov), r, i68, i95


def hpd_thresholds(log_prob: FloatArray, weights: FloatArray,
                   levels: Sequence[float]) -> tuple[float, ...]:
    """Log-posterior thresholds t with P(log p >= t) = level under the weighted samples."""
    order = np.argsort(-log_prob, kind="stable")
    cum = np.cumsum(weights[order]) / np.sum(weights)
    return tuple(float(log_prob[order[min(int(np.searchsorted(cum, lev)), cum.size - 1)]])
                 for lev in levels)


# ---- particle filter calibration ------------------------------------------------------


@dataclass(frozen=True)
class CloudCalibration:
    """A particle cloud's Gaussian summary against the posterior mode nearest to it.

    ``covariance_ratio``: eigenvalues of C_post^-1/2 C_cloud C_post^-1/2 (all 1 when the
    cloud's covariance is calibrated; below 1 overconfident, above 1 too wide).
    ``mean_nees``: (m_cloud - m_post)^T C_cloud^-1 (m_cloud - m_post).
    ``kl_posterior_to_cloud``: KL(N(m_post, C_post) || N(m_cloud, C_cloud)) in nats.
    ``nees_truth`` / ``nees_truth_posterior``: NEES of a true pose under the cloud's and the
    posterior's Gaussian (about 3 on average when calibrated), None without a truth.
    """

    mode: int
    cloud_mean: FloatArray
    cloud_cov: FloatArray
    covariance_ratio: FloatArray
    mean_nees: float
    kl_posterior_to_cloud: float
    nees_truth: float | None
    nees_truth_posterior: float | None


def compare_cloud(
    result: PosteriorResult, particles: FloatArray, weights: FloatArray | None = None,
    truth: FloatArray | None = None,
) -> CloudCalibration:
    """Is a particle filter's covariance honest? Compare its cloud with the posterior."""
    particles = np.asarray(particles, dtype=np.float64)
    if particles.ndim != 2 or particles.shape[1] != NDIM or particles.shape[0] < NDIM + 1:
        raise ValueError(f"particles must have shape (n >= 4, 3), got {particles.shape}")
    w = np.ones(particles.shape[0]) if weights is None else np.asarray(weights, float)
    w = w / w.sum()
    c = mean_resultant(particles[:, 2], w)[0]
    un = _unwrap_about(particles, c)
    m_cloud = np.array([w @ un[:, 0], w @ un[:, 1], c])
    d_cloud = pose_difference(particles, m_cloud)
    c_cloud = (d_cloud * w[:, None]).T @ d_cloud / (1.0 - np.sum(w**2))
    dist = [float(np.sum(pose_difference(m.mean, m_cloud) ** 2)) for m in result.modes]
    k = int(np.argmin(dist))
    m_post, c_post = result.modes[k].mean, result.modes[k].cov
    lp = np.linalg.cholesky(c_post)
    lp_inv = np.linalg.inv(lp)
    ratio = np.linalg.eigvalsh(lp_inv @ c_cloud @ lp_inv.T)
    dm = pose_difference(m_post, m_cloud)
    ic = np.linalg.inv(c_cloud)
    kl = 0.5 * (np.trace(ic @ c_post) + dm @ ic @ dm - NDIM
                + math.log(np.linalg.det(c_cloud) / np.linalg.det(c_post)))

    def nees(t: FloatArray, m: FloatArray, cov: FloatArray) -> float:
        e = pose_difference(t, m)
        return float(e @ np.linalg.solve(cov, e))

    t = None if truth is None else np.asarray(truth, dtype=np.float64)
    return CloudCalibration(
        mode=k, cloud_mean=m_cloud, cloud_cov=c_cloud, covariance_ratio=ratio,
        mean_nees=float(dm @ ic @ dm), kl_posterior_to_cloud=float(kl),
        nees_truth=None if t is None else nees(t, m_cloud, c_cloud),
        nees_truth_posterior=None if t is None else nees(t, m_post, c_post))
