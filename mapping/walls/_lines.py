"""Tangent lines from echo peaks: Hough voting, inliers and a range-only line fit.

A specular echo at range ``r`` heard from position ``p`` in direction ``phi`` (world frame)
fixes the wall's line: the line ``n(phi) . x = rho`` with ``n(phi) = (cos phi, sin phi)``
and ``rho = r + n(phi) . p`` is tangent to the circle of radius ``r`` about ``p``. The heat
map gives ``phi`` only folded and coarsely (``cos(phi - travel)`` to about the Doppler
resolution), so each peak votes along its sinusoid ``rho(phi) = r + n(phi) . p`` for every
``phi`` whose Doppler cosine ``cos(phi - travel)`` is within ``cos_tol`` of the measured one -
both sides. A wall seen from many poses collects its votes in one cell; the mirror side only
does so while the path is straight, and a point reflector (an inside corner) spreads its
votes along a sinusoid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage, optimize

from mapping.walls._peaks import PeakObservations

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class HoughSpace:
    """Accumulated votes ``votes[i_phi, i_rho]`` over line normals and offsets."""

    votes: FloatArray
    phi_rad: FloatArray
    rho_m: FloatArray


def doppler_cos(obs: PeakObservations) -> FloatArray:
    """Measured Doppler cosine ``cos(angle)`` of every peak."""
    return np.cos(obs.angle_rad)


def vote(obs: PeakObservations, cos_tol: float, phi_step_rad: float,
         rho_step_m: float) -> HoughSpace:
    """Hough accumulator of the tangent-line hypotheses of every peak (weights: peak values)."""
    phi = np.arange(-math.pi, math.pi, phi_step_rad)
    reach = float(np.max(np.hypot(obs.x_m, obs.y_m)) + np.max(obs.range_m)) + rho_step_m
    rho = np.arange(-reach, reach + rho_step_m, rho_step_m)
    votes = np.zeros((phi.size, rho.size))
    cos_m = doppler_cos(obs)
    w = obs.value / np.maximum(obs.noise, 1e-300)
    for i, f in enumerate(phi):
        c, s = math.cos(f), math.sin(f)
        ok = np.abs(np.cos(f - obs.travel_rad) - cos_m) <= cos_tol
        if not ok.any():
            continue
        r = obs.range_m[ok] + c * obs.x_m[ok] + s * obs.y_m[ok]
        j = np.rint((r - rho[0]) / rho_step_m).astype(np.int64)
        votes[i] += np.bincount(j, weights=np.sqrt(w[ok]), minlength=rho.size)[: rho.size]
    return HoughSpace(votes=votes, phi_rad=phi, rho_m=rho)


def smoothed(space: HoughSpace, sigma_cells: tuple[float, float]) -> FloatArray:
    """Votes blurred by ``sigma_cells`` (phi wraps): a line split between cells counts once."""
    return np.asarray(ndimage.gaussian_filter(space.votes, sigma_cells, mode=("wrap", "nearest")))


def line_residual(obs: PeakObservations, phi: float, rho: float) -> FloatArray:
    """Range residual ``r - (rho - n . p)`` of every peak against the line (phi, rho)."""
    return np.asarray(obs.range_m - (rho - math.cos(phi) * obs.x_m - math.sin(phi) * obs.y_m))


def cos_residual(obs: PeakObservations, phi: float) -> FloatArray:
    """Doppler-cosine residual of every peak against a wall of normal ``phi``."""
    return np.asarray(doppler_cos(obs) - np.cos(phi - obs.travel_rad))


def inliers(obs: PeakObservations, phi: float, rho: float, range_tol_m: float,
            cos_tol: float) -> BoolArray:
    """Peaks explained by the line: range within ``range_tol_m``, Doppler within ``cos_tol``."""
    return np.asarray((np.abs(line_residual(obs, phi, rho)) <= range_tol_m)
                      & (np.abs(cos_residual(obs, phi)) <= cos_tol))


@dataclass(frozen=True)
class LineFit:
    """Least-squares line ``n(phi) . x = rho`` with its covariance and residual scale."""

    phi_rad: float
    rho_m: float
    cov: FloatArray
    sigma_range_m: float


def fit_line(obs: PeakObservations, phi0: float, rho0: float, cos_sigma: float,
             range_sigma_m: float) -> LineFit:
    """Refine (phi, rho) on the peaks: ranges (precise) and Doppler cosines (coarse), robust."""
    w = np.sqrt(obs.value / np.maximum(obs.value.max(), 1e-300))

    def residuals(q: FloatArray) -> FloatArray:
        f, r = float(q[0]), float(q[1])
        return np.concatenate([w * line_residual(obs, f, r) / range_sigma_m,
                               w * cos_residual(obs, f) / cos_sigma])

    sol = optimize.least_squares(residuals, np.array([phi0, rho0]), loss="soft_l1",
                                 f_scale=2.0, x_scale=np.array([0.01, 0.01]))
    J = sol.jac
    n = obs.size
    res_r = line_residual(obs, float(sol.x[0]), float(sol.x[1]))
    scale = float(np.sqrt(np.average(res_r ** 2, weights=w ** 2))) if n else range_sigma_m
    try:
        cov = np.linalg.inv(J.T @ J) * max(scale / range_sigma_m, 1.0) ** 2
    except np.linalg.LinAlgError:
        cov = np.full((2, 2), np.inf)
    return LineFit(phi_rad=float(math.remainder(sol.x[0], 2 * math.pi)), rho_m=float(sol.x[1]),
                   cov=cov, sigma_range_m=scale)


def specular_points(obs: PeakObservations, phi: float) -> FloatArray:
    """Where each peak's echo touched the wall of normal ``phi``: ``p + r n``, shape (n, 2)."""
    n = np.array([math.cos(phi), math.sin(phi)])
    return np.stack([obs.x_m, obs.y_m], axis=1) + obs.range_m[:, None] * n
