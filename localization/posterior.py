"""Offline posterior analysis of the pose (x, y, heading) with emcee.

The posterior of one block or of a window of consecutive blocks tied together by odometry,

    log p(theta | H_0..H_{K-1}) = log prior(theta) + sum_k log L(H_k | theta (+) u_k, G),

where ``theta`` is the pose at the first block's midpoint, ``u_k`` the odometry offset of block
``k`` (exact arc composition of speed and yaw rate over the block duration) and ``L`` the
localization sensor model (issue 6; the heat map of paper Sec. 2.1, eq. 1, scored against the
map G of eq. 5). Everything here takes the likelihood as a callable ``poses (n, 3) -> (n,)``,
so any sensor model (or a known Gaussian for tests) plugs into the same code path.

Pipeline (:func:`iter_posterior` / :func:`sample_posterior`):

1. the log posterior on a coarse grid over (x, y, heading) (:func:`grid_log_posterior`);
2. well-separated modes of that grid and their masses by persistence clustering
   (:func:`find_grid_modes`; Chazal et al., "Persistence-based clustering", J. ACM 2013);
3. one ``emcee.EnsembleSampler`` per mode (emcee has no tempering between modes), walkers drawn
   from the mode's grid cells or from a particle cloud, never a single point (emcee issue 423),
   moves DEMove 0.8 + snooker 0.2 (:class:`SnookerMove`; emcee's own DESnookerMove is
   biased), run until the kept chain is >= 50 integrated autocorrelation times or a step cap;
4. per mode a fine local grid of the same log posterior: the mode's mass (integral) and the
   reference for a divergence and for the coverage of the sampler's 68/95 % HPD regions.

Heading is wrapped to (-pi, pi] inside the log posterior; each ensemble samples heading on the
window [c - pi, c + pi) around its mode's circular mean c, which is the same density on the
circle without a seam near the mode (a mode at +-pi does not split in two).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import emcee
import numpy as np
from numpy.typing import NDArray

from localization.sensor import SensorTables, pose_log_likelihood, prepare_measurement
from mapping.heatmap import HeatMap, heatmap_of_run
from mapping.runfile import Run

FloatArray = NDArray[np.float64]
LogLikelihood = Callable[[FloatArray], FloatArray]
"""``poses (n, 3) [x_m, y_m, heading_rad] -> log-likelihood (n,)``; heading arrives wrapped."""

NDIM = 3
TWO_PI = 2.0 * math.pi


# ---- angles and poses -----------------------------------------------------------------
def wrap_angle(a: FloatArray | float) -> FloatArray:
    """Wrap angles to (-pi, pi]."""
    w = np.mod(np.asarray(a, dtype=np.float64) + math.pi, TWO_PI) - math.pi
    return np.where(w == -math.pi, math.pi, w)


def circular_mean(a: FloatArray, weights: FloatArray | None = None) -> tuple[float, float]:
    """Circular mean of angles ``a`` and the mean resultant length R in [0, 1]."""
    w = np.ones_like(a) if weights is None else np.asarray(weights, dtype=np.float64)
    c = float(np.sum(w * np.cos(a)) / np.sum(w))
    s = float(np.sum(w * np.sin(a)) / np.sum(w))
    return math.atan2(s, c), math.hypot(c, s)


def circular_std(resultant_length: float) -> float:
    """Circular standard deviation sqrt(-2 ln R) in radians (inf for R = 0)."""
    return math.sqrt(-2.0 * math.log(resultant_length)) if resultant_length > 0 else math.inf


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


def log_posterior(theta: FloatArray, loglik: LogLikelihood, prior: PosePrior) -> FloatArray:
    """Unnormalized log posterior (n,) of poses ``theta`` (n, 3); heading is wrapped inside.

    Only poses inside the prior's support are passed to ``loglik``; NaN log-likelihoods count
    as -inf (emcee rejects such proposals instead of failing).
    """
    theta = np.atleast_2d(np.asarray(theta, dtype=np.float64))
    lp = prior.log_density(theta)
    ok = np.isfinite(lp)
    if ok.any():
        poses = theta[ok].copy()
        poses[:, 2] = wrap_angle(poses[:, 2])
        ll = np.asarray(loglik(poses), dtype=np.float64)
        lp[ok] += np.where(np.isnan(ll), -np.inf, ll)
    return lp


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


# ---- settings, results ----------------------------------------------------------------
@dataclass(frozen=True)
class PosteriorSettings:
    """Parameters of :func:`iter_posterior`.

    Attributes
    ----------
    n_walkers : int
        Walkers per ensemble (one ensemble per mode), >= 2 * 3.
    n_steps : int
        First batch of steps per ensemble, >= 1.
    max_steps : int
        Cap on steps per ensemble while extending towards ``tau_multiple`` autocorrelation times.
    tau_multiple : float
        Required kept chain length in integrated autocorrelation times (emcee advice: 50).
    de_weight : float
        Share of DEMove in the move mixture; the rest is a snooker move (emcee docs: 0.8/0.2).
    snooker : {"corrected", "emcee"}
        Which snooker move: :class:`SnookerMove` (default) or emcee's biased DESnookerMove.
    grid_step_m, grid_heading_step_rad : float
        Coarse global grid for mode finding and masses.
    persistence_nats, min_mode_mass, mass_level : float
        Mode finding, see :func:`find_grid_modes`.
    local_grid_cells : int
        Cells per axis of each mode's fine reference grid.
    local_grid_sigmas : float
        Half-width of that grid in posterior standard deviations.
    compare_bins : int
        Bins per axis of the shared histogram comparing samples with the grid posterior.
    """

    n_walkers: int = 32
    n_steps: int = 1000
    max_steps: int = 20_000
    tau_multiple: float = 50.0
    de_weight: float = 0.8
    snooker: str = "corrected"
    grid_step_m: float = 0.05
    grid_heading_step_rad: float = math.radians(10.0)
    persistence_nats: float = 3.0
    min_mode_mass: float = 0.01
    mass_level: float = 0.999
    local_grid_cells: int = 25
    local_grid_sigmas: float = 4.5
    compare_bins: int = 8

    def __post_init__(self) -> None:
        if self.n_walkers < 2 * NDIM:
            raise ValueError(f"n_walkers must be >= 2 * dim = {2 * NDIM}, got {self.n_walkers}")
        if self.n_steps < 1:
            raise ValueError(f"n_steps must be >= 1, got {self.n_steps}")
        if self.max_steps < self.n_steps:
            raise ValueError(f"max_steps must be >= n_steps = {self.n_steps}, "
                             f"got {self.max_steps}")
        if not self.tau_multiple > 0:
            raise ValueError(f"tau_multiple must be > 0, got {self.tau_multiple}")
        if not 0 <= self.de_weight <= 1:
            raise ValueError(f"de_weight must be in [0, 1], got {self.de_weight}")
        if self.snooker not in ("corrected", "emcee"):
            raise ValueError(f"snooker must be 'corrected' or 'emcee', got {self.snooker!r}")
        if not self.grid_step_m > 0:
            raise ValueError(f"grid_step_m must be > 0, got {self.grid_step_m}")
        if not 0 < self.grid_heading_step_rad <= math.pi:
            raise ValueError(f"grid_heading_step_rad must be in (0, pi], "
                             f"got {self.grid_heading_step_rad}")
        if self.local_grid_cells < 3:
            raise ValueError(f"local_grid_cells must be >= 3, got {self.local_grid_cells}")
        if not self.local_grid_sigmas > 0:
            raise ValueError(f"local_grid_sigmas must be > 0, got {self.local_grid_sigmas}")
        if self.compare_bins < 2:
            raise ValueError(f"compare_bins must be >= 2, got {self.compare_bins}")


@dataclass(frozen=True)
class GridComparison:
    """Sampler against the grid posterior on a shared histogram (one mode's box).

    ``hellinger`` in [0, 1]; ``hellinger_iid`` is the same distance for ``n_effective`` exact
    draws from the grid (what sampling noise alone gives); ``kl_grid_to_samples`` is
    KL(grid || samples) in nats with half-count smoothing; ``coverage68/95`` is the grid's
    mass inside the sampler's 68 / 95 % highest-density bins (ideal: about 0.68 / 0.95);
    ``outside`` the share of samples outside the box.
    """

    hellinger: float
    hellinger_iid: float
    kl_grid_to_samples: float
    coverage68: float
    coverage95: float
    outside: float
    n_effective: float


@dataclass(frozen=True)
class ModeSummary:
    """One mode: its mass, moments, intervals and chain diagnostics.

    ``mean`` is (x_m, y_m, circular mean heading_rad); ``cov`` the covariance with heading
    unwrapped about that mean; ``interval68/95`` (3, 2) equal-tailed intervals per axis
    (heading unwrapped, may leave (-pi, pi]); ``tau`` the integrated autocorrelation times of
    x, y, cos(heading), sin(heading) in steps; ``converged`` whether the kept chain is
    >= ``tau_multiple`` times the largest tau.
    """

    mass: float
    mass_coarse: float
    mean: FloatArray
    cov: FloatArray
    heading_resultant_length: float
    heading_circular_std_rad: float
    interval68: FloatArray
    interval95: FloatArray
    tau: FloatArray
    acceptance_fraction: float
    n_steps: int
    discard: int
    thin: int
    converged: bool
    comparison: GridComparison
    local_grid: GridPosterior = field(repr=False)


@dataclass(frozen=True)
class PosteriorResult:
    """Samples and diagnostics of the pose posterior.

    ``samples`` (n, 3) with heading wrapped to (-pi, pi]; ``weights`` (n,) sum to 1 and carry
    each mode's mass; ``mode_index`` (n,) the ensemble each sample came from;
    ``hpd_log_prob[i]`` the log-posterior threshold of the ``hpd_levels[i]`` highest-density
    region and ``hpd_volume[i]`` its volume in m^2 rad (from the modes' fine grids).
    """

    samples: FloatArray
    log_prob: FloatArray
    weights: FloatArray
    mode_index: NDArray[np.int64]
    modes: tuple[ModeSummary, ...]
    hpd_levels: tuple[float, ...]
    hpd_log_prob: tuple[float, ...]
    hpd_volume: tuple[float, ...]
    grid: GridPosterior = field(repr=False)
    grid_modes: GridModes = field(repr=False)
    settings: PosteriorSettings

    @property
    def converged(self) -> bool:
        """True when every ensemble reached ``tau_multiple`` autocorrelation times."""
        return all(m.converged for m in self.modes)


@dataclass(frozen=True)
class Progress:
    """One event of :func:`iter_posterior`: stage "grid", "sample" (per step) or "done"."""

    stage: str
    mode: int = 0
    n_modes: int = 0
    step: int = 0
    planned_steps: int = 0
    result: PosteriorResult | None = None


# ---- walkers and chains -------------------------------------------------------------------
def walkers_from_grid(
    grid: GridPosterior, modes: GridModes, k: int, n_walkers: int, rng: np.random.Generator
) -> FloatArray:
    """Walkers spread over mode ``k``'s grid cells (drawn by mass, jittered inside the cell).

    Headings are unwrapped about the mode's circular mean so no walker sits a turn away.
    """
    cells = np.flatnonzero(modes.label.ravel() == k)
    p = grid.prob.ravel()[cells]
    pick = cells[rng.choice(cells.size, size=n_walkers, p=p / p.sum())]
    pts = grid.poses()[pick]
    steps = np.array([_step(grid.x_m), _step(grid.y_m), _step(grid.heading_rad)])
    pts = pts + rng.uniform(-0.5, 0.5, size=pts.shape) * steps
    return _unwrap_about(pts, circular_mean(pts[:, 2], None)[0])


def walkers_from_cloud(
    particles: FloatArray, weights: FloatArray | None, n_walkers: int, rng: np.random.Generator,
    jitter: FloatArray | None = None,
) -> FloatArray:
    """Walkers resampled from a weighted particle cloud (n, 3), with a small jitter.

    The jitter (default: 5 % of the cloud's per-axis spread, at least 1 mm / 0.1 deg) keeps
    duplicated particles apart so the ensemble is not degenerate.
    """
    particles = np.asarray(particles, dtype=np.float64)
    if particles.ndim != 2 or particles.shape[1] != NDIM or particles.shape[0] < 1:
        raise ValueError(f"particles must have shape (n >= 1, 3), got {particles.shape}")
    w = np.full(particles.shape[0], 1.0) if weights is None else np.asarray(weights, float)
    if w.shape != (particles.shape[0],) or np.any(w < 0) or not w.sum() > 0:
        raise ValueError("weights must be (n,), non-negative, with a positive sum")
    c = circular_mean(particles[:, 2], w)[0]
    pts = _unwrap_about(particles[rng.choice(w.size, size=n_walkers, p=w / w.sum())], c)
    if jitter is None:
        jitter = np.maximum(0.05 * pts.std(axis=0), [1e-3, 1e-3, math.radians(0.1)])
    return pts + rng.normal(size=pts.shape) * jitter


def _unwrap_about(pts: FloatArray, center: float) -> FloatArray:
    out = np.array(pts, dtype=np.float64)
    out[:, 2] = center + wrap_angle(out[:, 2] - center)
    out[:, 2] = np.where(out[:, 2] >= center + math.pi, out[:, 2] - TWO_PI, out[:, 2])
    return out


@dataclass(frozen=True)
class ChainRun:
    """One ensemble's chain (steps, walkers, 3) and its convergence bookkeeping."""

    chain: FloatArray
    log_prob: FloatArray
    tau: FloatArray
    discard: int
    thin: int
    acceptance_fraction: float
    converged: bool


def _features(chain: FloatArray) -> FloatArray:
    return np.concatenate([chain[..., :2], np.cos(chain[..., 2:]), np.sin(chain[..., 2:])],
                          axis=-1)


def autocorr_check(chain: FloatArray, tau_multiple: float) -> tuple[FloatArray, int, bool]:
    """Integrated autocorrelation times after burn-in, the burn-in length, and the verdict.

    tau is estimated with ``emcee.autocorr.integrated_time(..., tol=0)`` on x, y, cos and sin of
    heading (heading itself is not used: it is an angle); burn-in is three times the largest tau
    of the full chain (at most half of it); converged means the kept part is at least
    ``tau_multiple`` times the largest tau of the kept part. A feature that never moved counts
    as tau = chain length (not converged).
    """
    n = chain.shape[0]
    feats = _features(chain)
    tau0 = _tau(feats)
    discard = int(min(3 * np.max(tau0), n // 2))
    tau = _tau(feats[discard:])
    return tau, discard, bool(n - discard >= tau_multiple * np.max(tau))


def _tau(feats: FloatArray) -> FloatArray:
    """emcee's integrated time; a feature that never moved (NaN) counts as the whole chain."""
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = emcee.autocorr.integrated_time(feats, tol=0)
    return np.asarray(np.where(np.isfinite(tau), tau, float(feats.shape[0])), dtype=np.float64)


class SnookerMove(emcee.moves.RedBlueMove):  # type: ignore[misc]
    """Differential-evolution snooker update (ter Braak & Vrugt 2008, Stat. Comput. 18:435).

    For walker x and three distinct walkers z, z1, z2 of the complementary sets: e is the unit
    vector along x - z, the proposal is ``q = x + gamma (e . (z1 - z2)) e`` and the Metropolis
    ratio carries the Jacobian ``(d - 1) log(|q - z| / |x - z|)``.

    Why not ``emcee.moves.DESnookerMove``: in emcee 3.1.4-3.1.6 it scales e by
    ``1 / sqrt(|x - z|)`` instead of ``1 / |x - z|`` (the step then depends on the distance
    to z, so the proposal is not symmetric) and uses ``(d - 1) / 2`` for the Jacobian. On a
    3-D Gaussian alone it samples about 0.4 times the true variance, and in the 0.8/0.2 mixture
    about 0.92 times (``tests/test_posterior.py`` keeps both numbers as a regression check).
    """

    def __init__(self, gammas: float = 1.7) -> None:
        self.gammas = gammas
        super().__init__(nsplits=4)

    def get_proposal(self, s: FloatArray, c: list[FloatArray], random: Any
                     ) -> tuple[FloatArray, FloatArray]:
        """Proposals for the walkers ``s`` from the complementary sets ``c``."""
        pool = np.concatenate(c, axis=0)
        ns, ndim = s.shape
        pick = np.argsort(random.rand(ns, pool.shape[0]), axis=1)[:, :3]  # 3 distinct each
        z, z1, z2 = pool[pick[:, 0]], pool[pick[:, 1]], pool[pick[:, 2]]
        delta = s - z
        norm = np.linalg.norm(delta, axis=1)
        e = delta / np.where(norm > 0, norm, 1.0)[:, None]
        q = s + self.gammas * np.sum(e * (z1 - z2), axis=1)[:, None] * e
        with np.errstate(divide="ignore"):
            factor = (ndim - 1.0) * (np.log(np.linalg.norm(q - z, axis=1)) - np.log(norm))
        return q, np.where(norm > 0, factor, -np.inf)


def make_moves(de_weight: float, snooker: str = "corrected") -> list[tuple[Any, float]]:
    """The move mixture: DEMove with weight ``de_weight``, a snooker move with the rest.

    ``snooker="corrected"`` uses :class:`SnookerMove`; ``"emcee"`` emcee's DESnookerMove
    (biased, kept for comparison).
    """
    if snooker not in ("corrected", "emcee"):
        raise ValueError(f"snooker must be 'corrected' or 'emcee', got {snooker!r}")
    sn = SnookerMove() if snooker == "corrected" else emcee.moves.DESnookerMove()
    moves = [(emcee.moves.DEMove(), de_weight), (sn, 1.0 - de_weight)]
    return [(m, w) for m, w in moves if w > 0]


def run_ensemble(
    log_prob_fn: Callable[[FloatArray], FloatArray],
    p0: FloatArray,
    settings: PosteriorSettings,
    rng: np.random.Generator,
) -> Generator[tuple[int, int], None, ChainRun]:
    """Run one emcee ensemble from ``p0``, extending until converged or ``max_steps``.

    A generator: yields ``(step, planned_steps)`` after every step and returns the
    :class:`ChainRun` (``result = yield from run_ensemble(...)``). emcee 3 has no seed argument;
    its RandomState is seeded through the initial :class:`emcee.State`'s ``random_state``, from
    an integer drawn from ``rng``.
    """
    moves = make_moves(settings.de_weight, settings.snooker)
    sampler = emcee.EnsembleSampler(p0.shape[0], NDIM, log_prob_fn, moves=moves, vectorize=True)
    seed = int(rng.integers(2**32 - 1))
    state = emcee.State(p0, random_state=np.random.RandomState(seed).get_state())
    planned = settings.n_steps
    done = 0
    while True:
        for step_state in sampler.sample(state, iterations=planned - done, store=True):
            state = step_state
            done += 1
            yield done, planned
        chain = sampler.get_chain()
        tau, discard, ok = autocorr_check(chain, settings.tau_multiple)
        if ok or done >= settings.max_steps:
            break
        want = int(math.ceil(1.25 * (settings.tau_multiple * np.max(tau) + discard)))
        planned = min(settings.max_steps, max(want, done + settings.n_steps // 2, done + 1))
    thin = max(1, int(0.5 * np.min(tau)))
    return ChainRun(chain, sampler.get_log_prob(), tau, discard, thin,
                    float(np.mean(sampler.acceptance_fraction)), ok)


# ---- per-mode reference grid, comparison and summaries --------------------------------
def mode_heading_center(grid: GridPosterior, modes: GridModes, k: int) -> float:
    """Mass-weighted circular mean heading of mode ``k``'s grid cells."""
    sel = modes.label == k
    h = np.broadcast_to(grid.heading_rad, grid.log_prob.shape)[sel]
    return circular_mean(h, grid.prob[sel])[0]


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
    c, r = circular_mean(samples[:, 2])
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


# ---- the pipeline ---------------------------------------------------------------------
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


def iter_posterior(
    loglik: LogLikelihood,
    prior: PosePrior,
    rng: np.random.Generator,
    settings: PosteriorSettings | None = None,
    grid: GridPosterior | None = None,
    cloud: tuple[FloatArray, FloatArray | None] | None = None,
) -> Iterator[Progress]:
    """Sample the pose posterior mode by mode; a generator of :class:`Progress` events.

    Parameters
    ----------
    loglik : callable
        Vectorized log-likelihood, e.g. from :func:`window_log_likelihood`.
    prior : PosePrior
        Box prior (its ``heading_center_rad`` is ignored: each mode gets its own window).
    rng : numpy.random.Generator
        Source of all randomness (walker draws, emcee's seed, the iid baseline).
    settings : PosteriorSettings, optional
    grid : GridPosterior, optional
        A precomputed coarse grid posterior (e.g. from the grid filter); computed from
        ``loglik`` and ``prior`` at ``settings.grid_step_m`` / ``grid_heading_step_rad``
        otherwise.
    cloud : (particles (n, 3), weights (n,) or None), optional
        A particle filter's cloud; a mode's walkers start from its particles when at least
        ``n_walkers`` of them fall in that mode, else from the mode's grid cells.

    Yields
    ------
    Progress
        "grid" once, "sample" after every MCMC step, then "done" with ``result`` set.
    """
    s = settings if settings is not None else PosteriorSettings()
    global_prior = prior.with_heading_center(None)
    if grid is None:
        yield Progress("grid")
        grid = grid_log_posterior(
            lambda t: log_posterior(t, loglik, global_prior),
            _axis(prior.x_min_m, prior.x_max_m, s.grid_step_m),
            _axis(prior.y_min_m, prior.y_max_m, s.grid_step_m),
            full_turn_headings(s.grid_heading_step_rad))
    if not np.isfinite(grid.log_prob).any():
        raise ValueError("the log posterior is -inf on every grid cell: no pose is plausible")
    modes = find_grid_modes(grid, s.mass_level, s.persistence_nats, s.min_mode_mass)
    cloud_labels = None
    if cloud is not None:
        cloud_labels = _cell_labels(grid, modes, np.asarray(cloud[0], dtype=np.float64))
    parts = []
    for k in range(modes.n_modes):
        c = mode_heading_center(grid, modes, k)
        mode_prior = global_prior.with_heading_center(c)

        def fn(t: FloatArray, mp: PosePrior = mode_prior) -> FloatArray:
            return log_posterior(t, loglik, mp)

        if cloud is not None and cloud_labels is not None and \
                int(np.sum(cloud_labels == k)) >= s.n_walkers:
            sel = cloud_labels == k
            w = None if cloud[1] is None else np.asarray(cloud[1], dtype=np.float64)[sel]
            p0 = walkers_from_cloud(np.asarray(cloud[0])[sel], w, s.n_walkers, rng)
        else:
            p0 = walkers_from_grid(grid, modes, k, s.n_walkers, rng)
        p0 = _unwrap_about(p0, c)
        gen = run_ensemble(fn, p0, s, rng)
        while True:
            try:
                step, planned = next(gen)
            except StopIteration as stop:
                run: ChainRun = stop.value
                break
            yield Progress("sample", k, modes.n_modes, step, planned)
        parts.append(_mode_part(run, fn, c, s, rng))
    yield Progress("done", modes.n_modes, modes.n_modes, result=_assemble(parts, grid, modes, s))


@dataclass(frozen=True)
class _ModePart:
    run: ChainRun
    samples: FloatArray
    log_prob: FloatArray
    grid: GridPosterior
    comparison: GridComparison


def _mode_part(run: ChainRun, fn: Callable[[FloatArray], FloatArray], center: float,
               s: PosteriorSettings, rng: np.random.Generator) -> _ModePart:
    kept = run.chain[run.discard::run.thin]
    samples = kept.reshape(-1, NDIM)
    lp = run.log_prob[run.discard::run.thin].ravel()
    fine = local_grid(fn, samples, center, s.local_grid_cells, s.local_grid_sigmas)
    n_eff = run.chain.shape[1] * (run.chain.shape[0] - run.discard) / float(np.max(run.tau))
    return _ModePart(run, samples, lp, fine, compare_with_grid(samples, fine, s.compare_bins,
                                                               n_eff, rng))


def merge_overlapping(parts: list[_ModePart], coarse_mass: FloatArray,
                      max_mahalanobis: float = 2.0) -> tuple[list[_ModePart], FloatArray]:
    """Merge ensembles that ended in the same place (a broad mode split on the coarse grid).

    Ensembles i < j merge when their means are within ``max_mahalanobis`` under
    ``cov_i + cov_j``: samples are pooled (chain diagnostics stay those of i), the mode's
    fine grid is the one with the larger integral (they cover the same mass), coarse masses
    add up.
    """
    parts, coarse = list(parts), list(coarse_mass)
    merged = True
    while merged:
        merged = False
        stats = [summarize_samples(p.samples)[:2] for p in parts]
        for i in range(len(parts)):
            for j in range(i + 1, len(parts)):
                d = _pose_diff(stats[j][0], stats[i][0])
                cov = stats[i][1] + stats[j][1]
                if d @ np.linalg.solve(cov + 1e-12 * np.eye(NDIM), d) < max_mahalanobis**2:
                    a, b = parts[i], parts[j]
                    keep = a.grid if a.grid.log_integral >= b.grid.log_integral else b.grid
                    parts[i] = _ModePart(a.run, np.concatenate([a.samples, b.samples]),
                                         np.concatenate([a.log_prob, b.log_prob]), keep,
                                         a.comparison)
                    coarse[i] += coarse.pop(j)
                    parts.pop(j)
                    merged = True
                    break
            if merged:
                break
    return parts, np.array(coarse)


def _assemble(parts: list[_ModePart], grid: GridPosterior, modes: GridModes,
              s: PosteriorSettings) -> PosteriorResult:
    parts, coarse_mass = merge_overlapping(parts, modes.mass)
    log_int = np.array([p.grid.log_integral for p in parts])
    if np.all(np.isfinite(log_int)):
        mass = np.exp(log_int - np.max(log_int))
        mass /= mass.sum()
    else:
        mass = coarse_mass.copy()
    order = np.argsort(-mass, kind="stable")
    parts = [parts[k] for k in order]
    mass, coarse_mass = mass[order], coarse_mass[order]
    summaries = []
    for k, p in enumerate(parts):
        mean, cov, r, i68, i95 = summarize_samples(p.samples)
        summaries.append(ModeSummary(
            mass=float(mass[k]), mass_coarse=float(coarse_mass[k]), mean=mean, cov=cov,
            heading_resultant_length=r, heading_circular_std_rad=circular_std(r),
            interval68=i68, interval95=i95, tau=p.run.tau,
            acceptance_fraction=p.run.acceptance_fraction, n_steps=int(p.run.chain.shape[0]),
            discard=p.run.discard, thin=p.run.thin, converged=p.run.converged,
            comparison=p.comparison, local_grid=p.grid))
    samples = np.concatenate([p.samples for p in parts])
    samples[:, 2] = wrap_angle(samples[:, 2])
    log_prob = np.concatenate([p.log_prob for p in parts])
    weights = np.concatenate([np.full(p.samples.shape[0], mass[k] / p.samples.shape[0])
                              for k, p in enumerate(parts)])
    index = np.concatenate([np.full(p.samples.shape[0], k, dtype=np.int64)
                            for k, p in enumerate(parts)])
    levels = (0.68, 0.95)
    thresholds = hpd_thresholds(log_prob, weights, levels)
    volumes = tuple(float(sum(np.sum(p.grid.log_prob >= t) * p.grid.cell_volume for p in parts))
                    for t in thresholds)
    return PosteriorResult(samples, log_prob, weights, index, tuple(summaries), levels,
                           thresholds, volumes, grid, modes, s)


def sample_posterior(
    loglik: LogLikelihood,
    prior: PosePrior,
    rng: np.random.Generator,
    settings: PosteriorSettings | None = None,
    grid: GridPosterior | None = None,
    cloud: tuple[FloatArray, FloatArray | None] | None = None,
) -> PosteriorResult:
    """Run :func:`iter_posterior` to the end and return its :class:`PosteriorResult`."""
    for event in iter_posterior(loglik, prior, rng, settings, grid, cloud):
        if event.result is not None:
            return event.result
    raise RuntimeError("iter_posterior ended without a result")  # pragma: no cover


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


def _pose_diff(a: FloatArray, b: FloatArray) -> FloatArray:
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    d[..., 2] = wrap_angle(d[..., 2])
    return d


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
    c = circular_mean(particles[:, 2], w)[0]
    un = _unwrap_about(particles, c)
    m_cloud = np.array([w @ un[:, 0], w @ un[:, 1], c])
    d_cloud = _pose_diff(particles, m_cloud)
    c_cloud = (d_cloud * w[:, None]).T @ d_cloud / (1.0 - np.sum(w**2))
    dist = [float(np.sum(_pose_diff(m.mean, m_cloud) ** 2)) for m in result.modes]
    k = int(np.argmin(dist))
    m_post, c_post = result.modes[k].mean, result.modes[k].cov
    lp = np.linalg.cholesky(c_post)
    lp_inv = np.linalg.inv(lp)
    ratio = np.linalg.eigvalsh(lp_inv @ c_cloud @ lp_inv.T)
    dm = _pose_diff(m_post, m_cloud)
    ic = np.linalg.inv(c_cloud)
    kl = 0.5 * (np.trace(ic @ c_post) + dm @ ic @ dm - NDIM
                + math.log(np.linalg.det(c_cloud) / np.linalg.det(c_post)))

    def nees(t: FloatArray, m: FloatArray, cov: FloatArray) -> float:
        e = _pose_diff(t, m)
        return float(e @ np.linalg.solve(cov, e))

    t = None if truth is None else np.asarray(truth, dtype=np.float64)
    return CloudCalibration(
        mode=k, cloud_mean=m_cloud, cloud_cov=c_cloud, covariance_ratio=ratio,
        mean_nees=float(dm @ ic @ dm), kl_posterior_to_cloud=float(kl),
        nees_truth=None if t is None else nees(t, m_cloud, c_cloud),
        nees_truth_posterior=None if t is None else nees(t, m_post, c_post))


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

    Heat maps come from :func:`mapping.heatmap.heatmap_of_run` (paper eq. 1), odometry from
    the run; the parameter is the pose of block ``start + anchor``, whose tracked pose (3,)
    is returned too (NaN where untracked).
    """
    check_block_range(start, stop, run.n_blocks)
    heat_maps = [heatmap_of_run(run, k) for k in range(start, stop)]
    loglik = sensor_window_log_likelihood(
        tables, heat_maps, run.speed_m_s[start:stop], run.yaw_rate_rad_s[start:stop],
        run.config.block_s, anchor)
    return loglik, np.asarray(run.pose[start + anchor], dtype=np.float64)


def result_arrays(result: PosteriorResult) -> dict[str, FloatArray]:
    """The result as flat arrays for an ``.npz`` record (see the README's posterior format)."""
    modes = result.modes
    return {
        "samples": result.samples,
        "log_prob": result.log_prob,
        "weights": result.weights,
        "mode_index": result.mode_index.astype(np.float64),
        "mode_mass": np.array([m.mass for m in modes]),
        "mode_mass_coarse": np.array([m.mass_coarse for m in modes]),
        "mode_mean": np.array([m.mean for m in modes]),
        "mode_cov": np.array([m.cov for m in modes]),
        "mode_interval68": np.array([m.interval68 for m in modes]),
        "mode_interval95": np.array([m.interval95 for m in modes]),
        "mode_heading_circular_std_rad": np.array([m.heading_circular_std_rad for m in modes]),
        "mode_tau": np.array([m.tau for m in modes]),
        "mode_acceptance": np.array([m.acceptance_fraction for m in modes]),
        "mode_n_steps": np.array([m.n_steps for m in modes], dtype=np.float64),
        "mode_converged": np.array([m.converged for m in modes], dtype=np.float64),
        "mode_hellinger": np.array([m.comparison.hellinger for m in modes]),
        "mode_hellinger_iid": np.array([m.comparison.hellinger_iid for m in modes]),
        "mode_kl": np.array([m.comparison.kl_grid_to_samples for m in modes]),
        "mode_coverage68": np.array([m.comparison.coverage68 for m in modes]),
        "mode_coverage95": np.array([m.comparison.coverage95 for m in modes]),
        "hpd_levels": np.array(result.hpd_levels),
        "hpd_log_prob": np.array(result.hpd_log_prob),
        "hpd_volume_m2_rad": np.array(result.hpd_volume),
    }
