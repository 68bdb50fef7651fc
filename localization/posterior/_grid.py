"""The pose posterior on a regular (x, y, heading) grid, and its modes.

Steps 1, 2 and 4 of :mod:`localization.posterior`: the log posterior on a coarse grid
(:func:`grid_log_posterior`), well-separated modes and their masses by persistence clustering
(:func:`find_grid_modes`; Chazal et al., "Persistence-based clustering", J. ACM 2013) and each
mode's fine reference grid (:func:`local_grid`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.posterior._window import TWO_PI, FloatArray
from mapping.angles import mean_resultant, wrap_angle


# ---- grid posterior -------------------------------------------------------------------
@dataclass(frozen=True)
class GridPosterior:
    """Log posterior on a regular (x, y, heading) grid of cell centres.

    ``log_prob[ix, iy, ih]`` at (x_m[ix], y_m[iy], heading_rad[ih]); ``prob`` is the normalized
    cell mass (sums to 1). ``periodic`` is True when the heading axis covers the full circle.
    """

    x_m: FloatArray
    y_m: FloatArray
    heading_rad: FloatArray
    log_prob: FloatArray
    periodic: bool

    @property
    def cell_volume(self) -> float:
        """Cell volume in m^2 rad."""
        return float(_step(self.x_m) * _step(self.y_m) * _step(self.heading_rad))

    @property
    def prob(self) -> FloatArray:
        """Normalized cell probabilities (same shape as ``log_prob``)."""
        m = float(np.max(self.log_prob))
        if not np.isfinite(m):
            return np.full(self.log_prob.shape, 1.0 / self.log_prob.size)
        p = np.exp(self.log_prob - m)
        return p / p.sum()

    @property
    def log_integral(self) -> float:
        """log of sum(exp(log_prob)) * cell_volume: the grid's integral of the posterior."""
        m = float(np.max(self.log_prob))
        if not np.isfinite(m):
            return -math.inf
        return m + math.log(float(np.sum(np.exp(self.log_prob - m))) * self.cell_volume)

    def poses(self) -> FloatArray:
        """All cell centres as poses (n_cells, 3), C order of ``log_prob``."""
        g = np.meshgrid(self.x_m, self.y_m, self.heading_rad, indexing="ij")
        return np.stack([a.ravel() for a in g], axis=1)


def _step(axis: FloatArray) -> float:
    return float(axis[1] - axis[0]) if axis.size > 1 else 1.0


def grid_log_posterior(
    log_prob_fn: Callable[[FloatArray], FloatArray],
    x_m: FloatArray,
    y_m: FloatArray,
    heading_rad: FloatArray,
    chunk: int = 65536,
) -> GridPosterior:
    """Evaluate a vectorized log posterior on the grid x_m x y_m x heading_rad (cell centres).

    Parameters
    ----------
    log_prob_fn : callable
        ``theta (n, 3) -> (n,)``, e.g. ``lambda t: log_posterior(t, loglik, prior)``.
    x_m, y_m, heading_rad : ndarray
        Increasing, evenly spaced axes. The heading axis is periodic when it spans a full turn
        (n steps of 2 pi / n).
    chunk : int
        Poses per call of ``log_prob_fn`` (memory bound).
    """
    axes = [np.asarray(a, dtype=np.float64) for a in (x_m, y_m, heading_rad)]
    for a, name in zip(axes, ("x_m", "y_m", "heading_rad"), strict=True):
        if a.ndim != 1 or a.size < 1 or (a.size > 1 and not np.allclose(np.diff(a), a[1] - a[0])
                                         or (a.size > 1 and a[1] <= a[0])):
            raise ValueError(f"{name} must be a non-empty, increasing, evenly spaced 1-D axis")
    if chunk < 1:
        raise ValueError(f"chunk must be >= 1, got {chunk}")
    h = axes[2]
    periodic = h.size > 1 and math.isclose(h.size * (h[1] - h[0]), TWO_PI, rel_tol=1e-9)
    grid = GridPosterior(axes[0], axes[1], h, np.empty(0), periodic)
    poses = grid.poses()
    lp = np.concatenate([np.asarray(log_prob_fn(poses[i:i + chunk]), dtype=np.float64)
                         for i in range(0, poses.shape[0], chunk)])
    lp = np.where(np.isnan(lp), -np.inf, lp)
    return GridPosterior(axes[0], axes[1], h, lp.reshape(x_m.size, y_m.size, h.size), periodic)


def full_turn_headings(heading_step_rad: float) -> FloatArray:
    """Heading cell centres covering (-pi, pi] with about ``heading_step_rad`` spacing."""
    if not 0 < heading_step_rad <= math.pi:
        raise ValueError(f"heading_step_rad must be in (0, pi], got {heading_step_rad}")
    n = max(2, int(round(TWO_PI / heading_step_rad)))
    return -math.pi + TWO_PI * (np.arange(n) + 0.5) / n


# ---- modes of the grid posterior ------------------------------------------------------
@dataclass(frozen=True)
class GridModes:
    """Well-separated modes of a grid posterior.

    ``label`` has the grid's shape: mode index per cell, -1 outside the retained cells.
    ``mass[k]`` is mode k's share of the grid mass (masses sum to 1 over retained modes),
    ``peak[k]`` the (x, y, heading) of its best cell; modes are sorted by mass, largest first.
    """

    label: NDArray[np.int64]
    mass: FloatArray
    peak: FloatArray

    @property
    def n_modes(self) -> int:
        """Number of modes."""
        return int(self.mass.size)


def find_grid_modes(
    grid: GridPosterior,
    mass_level: float = 0.999,
    persistence_nats: float = 3.0,
    min_mode_mass: float = 0.01,
    max_cells: int = 200_000,
) -> GridModes:
    """Modes of a grid posterior by persistence-based clustering (ToMATo, Chazal et al. 2013).

    Cells of the highest-density region holding ``mass_level`` of the mass are visited from
    the most to the least probable and joined to their 26-neighbours (heading periodic when
    the grid is). Where two clusters meet, the lower one survives as a separate mode only when
    its peak stands at least ``persistence_nats`` above the saddle; otherwise it is merged.
    Clusters that never touch within that region are separate modes whatever their depth.
    Modes below ``min_mode_mass`` are dropped and the rest renormalized.
    """
    if not 0 < mass_level <= 1:
        raise ValueError(f"mass_level must be in (0, 1], got {mass_level}")
    if persistence_nats < 0:
        raise ValueError(f"persistence_nats must be >= 0, got {persistence_nats}")
    if not 0 <= min_mode_mass < 1:
        raise ValueError(f"min_mode_mass must be in [0, 1), got {min_mode_mass}")
    p = grid.prob.ravel()
    order = np.argsort(-p, kind="stable")
    n_keep = int(np.searchsorted(np.cumsum(p[order]), mass_level * p.sum()) + 1)
    order = order[: min(n_keep, max_cells, p.size)]
    root = _persistence_union(grid, order, persistence_nats)
    labels_flat = np.full(p.size, -1, dtype=np.int64)
    roots, inverse = np.unique(root[order], return_inverse=True)
    mass = np.bincount(inverse, weights=p[order])
    keep = np.flatnonzero(mass >= min_mode_mass * mass.sum())
    if keep.size == 0:
        keep = np.array([int(np.argmax(mass))])
    keep = keep[np.argsort(-mass[keep], kind="stable")]
    remap = np.full(roots.size, -1, dtype=np.int64)
    remap[keep] = np.arange(keep.size)
    labels_flat[order] = remap[inverse]
    peaks = grid.poses()[roots[keep]]
    return GridModes(labels_flat.reshape(grid.log_prob.shape), mass[keep] / mass[keep].sum(),
                     peaks)


def _persistence_union(
    grid: GridPosterior, order: NDArray[np.intp], tau: float
) -> NDArray[np.int64]:
    """Union-find over ``order`` (descending density); returns the root cell of each cell."""
    shape = grid.log_prob.shape
    lp = grid.log_prob.ravel()
    parent = np.full(lp.size, -1, dtype=np.int64)
    offsets = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)
                        if (a, b, c) != (0, 0, 0)])

    def find(i: int) -> int:
        r = i
        while parent[r] != r:
            r = int(parent[r])
        while parent[i] != r:
            parent[i], i = r, int(parent[i])
        return r

    for cell in order:
        idx = np.array(np.unravel_index(int(cell), shape))
        nb = idx + offsets
        if grid.periodic:
            nb[:, 2] %= shape[2]
        ok = np.all((nb >= 0) & (nb < np.array(shape)), axis=1)
        flat = np.ravel_multi_index(tuple(nb[ok].T), shape)
        flat = flat[parent[flat] >= 0]
        parent[cell] = cell
        if flat.size == 0:
            continue
        rts = {find(int(f)) for f in flat}
        best = max(rts, key=lambda r: lp[r])
        parent[cell] = best
        for r in rts:
            if r != best and lp[r] - lp[cell] < tau:
                parent[r] = best
    out = np.full(lp.size, -1, dtype=np.int64)
    for c in order:
        out[c] = find(int(c))
    return out


# ---- per-mode reference grid, comparison and summaries --------------------------------
def mode_heading_center(grid: GridPosterior, modes: GridModes, k: int) -> float:
    """Mass-weighted circular mean heading of mode ``k``'s grid cells."""
    sel = modes.label == k
    h = np.broadcast_to(grid.heading_rad, grid.log_prob.shape)[sel]
    return mean_resultant(h, grid.prob[sel])[0]


def local_grid(
    log_prob_fn: Callable[[FloatArray], FloatArray],
    samples: FloatArray,
    heading_center_rad: float,
    n_cells: int,
    n_sigmas: float,
) -> GridPosterior:
    """A fine grid of ``log_prob_fn`` over a box of +-``n_sigmas`` standard deviations.

    ``samples`` (n, 3) have heading unwrapped about ``heading_center_rad``. When the heading
    box would reach half a turn the heading axis covers the full turn (periodic).
    """
    center = np.array([samples[:, 0].mean(), samples[:, 1].mean(), heading_center_rad])
    half = np.maximum(n_sigmas * samples.std(axis=0), [1e-3, 1e-3, math.radians(0.1)])
    axes = [center[i] + np.linspace(-half[i], half[i], n_cells) for i in range(2)]
    if half[2] >= math.pi * (1.0 - 1.0 / n_cells):
        h = heading_center_rad + full_turn_headings(TWO_PI / n_cells)
    else:
        h = center[2] + np.linspace(-half[2], half[2], n_cells)
    return grid_log_posterior(log_prob_fn, axes[0], axes[1], h)


def _axis(lo: float, hi: float, step: float) -> FloatArray:
    n = max(1, int(math.floor((hi - lo) / step)))
    return np.asarray(lo + 0.5 * (hi - lo - (n - 1) * step) + step * np.arange(n), dtype=np.float64)


def _cell_labels(grid: GridPosterior, modes: GridModes, poses: FloatArray) -> NDArray[np.int64]:
    idx = []
    for i, ax in enumerate((grid.x_m, grid.y_m)):
        idx.append(np.clip(np.round((poses[:, i] - ax[0]) / _step(ax)), 0, ax.size - 1))
    h = grid.heading_rad
    ih = np.round((wrap_angle(poses[:, 2]) - h[0]) / _step(h))
    ih = np.mod(ih, h.size) if grid.periodic else np.clip(ih, 0, h.size - 1)
    return modes.label[idx[0].astype(int), idx[1].astype(int), ih.astype(int)]
