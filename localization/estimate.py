"""Summaries of a weighted pose set: circular statistics, covariance, modes.

Headings are angles: their mean is the circular mean ``atan2(sum w sin h, sum w cos h)``
and deviations are wrapped to (-pi, pi] before any second moment is taken. Modes are found
by clustering: particles are binned on a coarse (x, y, heading) grid, bins holding
non-negligible weight are joined into connected components (the heading axis wraps
around), and each component is summarized by its weight, mean and covariance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from mapping.angles import circular_mean, pose_error, wrap_angle

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ClusterConfig:
    """Mode clustering and convergence test.

    Parameters
    ----------
    cell_m, heading_bins : float, int
        Bin size of the clustering grid (position, number of heading bins over 2 pi).
    min_bin_weight, rel_bin_weight : float
        Bins lighter than ``min_bin_weight`` or than ``rel_bin_weight`` times the heaviest
        bin belong to no mode (so a thin bridge of particles does not join two modes).
    max_modes : int
        Modes reported.
    refine_levels, split_share : int, float
        A mode wider than the convergence limits is clustered again on a grid twice as
        fine (up to ``refine_levels`` times) and split when two parts each hold
        ``split_share`` of its weight (:func:`find_modes`).
    converged_weight, converged_std_m, converged_std_rad : float
        ``converged`` when the best mode holds at least this weight and its position and
        heading standard deviations are below these.
    """

    cell_m: float = 0.25
    heading_bins: int = 12
    min_bin_weight: float = 1e-3
    rel_bin_weight: float = 0.02
    max_modes: int = 5
    refine_levels: int = 1
    split_share: float = 0.1
    converged_weight: float = 0.9
    converged_std_m: float = 0.15
    converged_std_rad: float = math.radians(15.0)


@dataclass(frozen=True)
class Mode:
    """One cluster of the pose set: its total weight, mean pose (3,) and covariance (3, 3)."""

    weight: float
    mean: FloatArray
    cov: FloatArray


@dataclass(frozen=True)
class PoseEstimate:
    """The filter's answer after one block.

    Attributes
    ----------
    pose : ndarray (3,)
        Mean (x_m, y_m, heading_rad) of the heaviest mode; heading in (-pi, pi].
    cov : ndarray (3, 3)
        Covariance of that mode (m^2, m rad, rad^2).
    mean_all, cov_all : ndarray (3,), (3, 3)
        Mean and covariance of the whole set.
    modes : tuple of Mode
        Heaviest first.
    ess : float
        Effective sample size after the update (before any resampling).
    converged : bool
        All weight in one compact mode (see :class:`ClusterConfig`).
    direction_observable : bool
        Whether this update used direction information.
    updated : bool
        Whether a measurement was applied (False: prediction only).
    model : str
        Sensor model used ("correlation", "range" or "none").
    likelihood_scale : float
        Share of the block's log-likelihood the particle filter applied (1: all of it; less
        when the update was tempered to keep ``min_ess_fraction`` of the particles, see
        :func:`localization.particle_filter.temper_to_ess`).
    status : {"converged", "uncertain", "lost"}
        The honest status (see :data:`TRACK_STATUSES`): ``converged`` only when the set is
        one compact mode, the pose is inside the map's coverage and (echo model) the block
        is explained at the estimate as well as tracked runs explain it at the true pose;
        ``lost`` when (echo model) consecutive blocks are not explained.
    fit : float
        Echo model: how well the estimate explains the block, the mean of the shares of
        measured peaks explained and of expected echoes heard, in [0, 1] (NaN for the G
        models and for a block without peaks).
    covered : bool
        Whether the estimate lies on a map cell with evidence (``WallMap.coverage``).
    refined : bool
        Whether ``pose`` and ``cov`` come from the Gaussian refinement of the converged mode
        (:mod:`localization.refine`) rather than from the particles of that mode (``modes``
        always hold the particles' view).
    reckoned : bool
        Whether ``pose`` and ``cov`` are dead reckoning from the last confirmed convergence
        (never with status ``converged``): the particles' mode lies far from it and the
        blocks do not prefer it by the prior odds of a kidnap (``modes`` hold it).
    reason : str
        Particle filter: why the status is not ``converged`` (one of
        :data:`STATUS_REASONS`; ``""`` when it is, or when the filter gives none).
    """

    pose: FloatArray
    cov: FloatArray
    mean_all: FloatArray
    cov_all: FloatArray
    modes: tuple[Mode, ...]
    ess: float
    converged: bool
    direction_observable: bool
    updated: bool
    model: str
    likelihood_scale: float = 1.0
    status: str = "uncertain"
    fit: float = math.nan
    covered: bool = True
    refined: bool = False
    reckoned: bool = False
    reason: str = ""




def default_start_cov() -> FloatArray:
    """The start covariance of a tracked start when none is given: 10 cm in x and y and
    10 deg in heading, independent (a fresh array each call)."""
    return np.diag([0.1**2, 0.1**2, math.radians(10.0) ** 2])


def weighted_mean_cov(poses: FloatArray, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mean (circular in heading) and covariance (heading deviations wrapped) of poses."""
    w = weights / weights.sum()
    mean = np.array([np.sum(w * poses[:, 0]), np.sum(w * poses[:, 1]),
                     circular_mean(poses[:, 2], w)])
    d = poses - mean
    d[:, 2] = wrap_angle(d[:, 2])
    cov = (d * w[:, None]).T @ d
    return mean, 0.5 * (cov + cov.T)



def nees(estimate: FloatArray, cov: FloatArray, truth: FloatArray) -> float:
    """Normalized estimation error squared ``e^T cov^-1 e`` (3 degrees of freedom)."""
    e = np.asarray(truth, dtype=np.float64) - estimate
    e[2] = float(wrap_angle(e[2]))
    return float(e @ np.linalg.solve(cov + 1e-12 * np.eye(3), e))


def find_modes(poses: FloatArray, weights: FloatArray, config: ClusterConfig) -> list[Mode]:
    """Cluster a weighted pose set into modes, heaviest first (see the module docstring).

    A component that is not compact (position or heading spread above the convergence
    limits) is clustered again on a grid twice as fine, up to ``config.refine_levels``
    times, and replaced by its parts when at least two of them each hold
    ``config.split_share`` of its weight: two modes a few decimetres and a few tens of
    degrees apart (a symmetric room's twins near its centre, a mirror pose next to the
    truth) touch on the coarse grid, and their average is a pose neither of them is.
    """
    w = weights / weights.sum()
    modes = []
    for sel in _split(poses, w, np.arange(poses.shape[0]), config.cell_m,
                      config.heading_bins, config, config.refine_levels):
        mean, cov = weighted_mean_cov(poses[sel], w[sel])
        modes.append(Mode(weight=float(w[sel].sum()), mean=mean, cov=cov))
    modes.sort(key=lambda m: -m.weight)
    return modes[: config.max_modes]


def _split(poses: FloatArray, w: FloatArray, idx: NDArray[np.int64], cell_m: float,
           heading_bins: int, config: ClusterConfig, levels: int) -> list[NDArray[np.int64]]:
    """Components (particle indices) of ``idx`` on a grid of ``cell_m`` x ``heading_bins``,
    each refined (:func:`find_modes`) while ``levels`` remain."""
    parts = _components(poses[idx], w[idx], cell_m, heading_bins, config)
    out: list[NDArray[np.int64]] = []
    for part in parts:
        sel = idx[part]
        if levels > 0 and sel.size > 1:
            _, cov = weighted_mean_cov(poses[sel], w[sel])
            wide = (math.sqrt(max(cov[0, 0] + cov[1, 1], 0.0)) > config.converged_std_m
                    or math.sqrt(max(cov[2, 2], 0.0)) > config.converged_std_rad)
            if wide:
                sub = _split(poses, w, sel, 0.5 * cell_m, 2 * heading_bins, config,
                             levels - 1)
                total = float(w[sel].sum())
                big = sum(float(w[s].sum()) >= config.split_share * total for s in sub)
                if big >= 2:
                    out.extend(sub)
                    continue
        out.append(sel)
    return out


def _components(poses: FloatArray, w: FloatArray, cell_m: float, heading_bins: int,
                config: ClusterConfig) -> list[NDArray[np.int64]]:
    """Connected components of the bins holding non-negligible weight (indices into poses)."""
    lo = poses[:, :2].min(axis=0)
    ij = np.floor((poses[:, :2] - lo) / cell_m).astype(np.int64)
    hb = np.floor((wrap_angle(poses[:, 2]) + np.pi) / (2 * np.pi) * heading_bins)
    hb = np.clip(hb.astype(np.int64), 0, heading_bins - 1)
    shape = (int(ij[:, 0].max()) + 1, int(ij[:, 1].max()) + 1, heading_bins)
    flat = np.ravel_multi_index((ij[:, 0], ij[:, 1], hb), shape)
    bin_w = np.bincount(flat, weights=w, minlength=int(np.prod(shape))).reshape(shape)
    level = max(config.min_bin_weight * float(w.sum()), config.rel_bin_weight * float(bin_w.max()))
    labels, n = ndimage.label(bin_w >= level, structure=np.ones((3, 3, 3)))
    labels = _merge_wrap(labels, n)
    particle_label = labels.ravel()[flat]
    return [np.flatnonzero(particle_label == lab)
            for lab in np.unique(particle_label[particle_label > 0])]


def _merge_wrap(labels: NDArray[np.int32], n: int) -> NDArray[np.int64]:
    """Join components that touch across the heading wrap (bin 0 next to the last bin)."""
    parent = np.arange(n + 1)

    def root(a: int) -> int:
        while parent[a] != a:
            a = int(parent[a])
        return a

    first, last = labels[:, :, 0], labels[:, :, -1]
    nx, ny = first.shape
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            a = first[max(dx, 0):nx + min(dx, 0), max(dy, 0):ny + min(dy, 0)]
            b = last[max(-dx, 0):nx + min(-dx, 0), max(-dy, 0):ny + min(-dy, 0)]
            for p, q in zip(a[(a > 0) & (b > 0)], b[(a > 0) & (b > 0)], strict=True):
                rp, rq = root(int(p)), root(int(q))
                if rp != rq:
                    parent[max(rp, rq)] = min(rp, rq)
    roots = np.array([root(i) for i in range(n + 1)])
    return roots[labels]


def summarize(
    poses: FloatArray, log_w: FloatArray, config: ClusterConfig, *, ess: float,
    direction_observable: bool, updated: bool, model: str, likelihood_scale: float = 1.0,
) -> PoseEstimate:
    """Build the :class:`PoseEstimate` of a particle set with normalized log-weights."""
    w = np.exp(log_w - log_w.max())
    mean_all, cov_all = weighted_mean_cov(poses, w)
    modes = find_modes(poses, w, config)
    best = modes[0] if modes else Mode(1.0, mean_all, cov_all)
    compact = (math.sqrt(max(best.cov[0, 0] + best.cov[1, 1], 0.0)) <= config.converged_std_m
               and math.sqrt(max(best.cov[2, 2], 0.0)) <= config.converged_std_rad)
    return PoseEstimate(
        pose=best.mean, cov=best.cov, mean_all=mean_all, cov_all=cov_all,
        modes=tuple(modes), ess=float(ess),
        converged=bool(best.weight >= config.converged_weight and compact),
        direction_observable=direction_observable, updated=updated, model=model,
        likelihood_scale=float(likelihood_scale),
        status="converged" if best.weight >= config.converged_weight and compact
        else "uncertain",
    )


@dataclass(frozen=True)
class TrackMetrics:
    """Errors of a pose track against tracked truth.

    Attributes
    ----------
    n_blocks : int
        Blocks with truth.
    blocks_to_converge : int or None
        First block from which every estimate stays within ``tol_m`` and ``tol_rad`` of the
        truth (None: never).
    position_rmse_m, heading_rmse_rad : float
        RMSE over the blocks from ``blocks_to_converge`` on (NaN if never converged).
    share_within_tol : float
        Share of all blocks with position error <= ``tol_m``.
    nees_mean : float
        Mean NEES (3 dof; ~3 when the covariance is honest) after convergence.
    position_rmse_all_m, heading_rmse_all_rad : float
        RMSE over every block with truth, converged or not (NaN only without truth): a run
        that never converges still has a number, and a late convergence shows in it.
    """

    n_blocks: int
    blocks_to_converge: int | None
    position_rmse_m: float
    heading_rmse_rad: float
    share_within_tol: float
    nees_mean: float
    position_rmse_all_m: float
    heading_rmse_all_rad: float


def track_metrics(poses: FloatArray, covs: FloatArray, truth: FloatArray,
                  tol_m: float = 0.1, tol_rad: float = math.radians(10.0)) -> TrackMetrics:
    """:class:`TrackMetrics` of estimated ``poses`` (n, 3) with ``covs`` (n, 3, 3) against
    ``truth`` (n, 3); rows with NaN truth are skipped."""
    ok = np.isfinite(truth).all(axis=1)
    poses, covs, truth = poses[ok], covs[ok], truth[ok]
    err = np.array([pose_error(p, t) for p, t in zip(poses, truth, strict=True)]).reshape(-1, 2)
    good = (err[:, 0] <= tol_m) & (err[:, 1] <= tol_rad)
    bad = np.flatnonzero(~good)
    start = 0 if bad.size == 0 else int(bad[-1]) + 1
    n = int(truth.shape[0])
    rmse_all = _rmse(err)
    if start >= n:
        return TrackMetrics(n, None, math.nan, math.nan,
                            float(np.mean(err[:, 0] <= tol_m)) if n else math.nan, math.nan,
                            *rmse_all)
    nees_vals = [nees(p, c, t) for p, c, t in zip(poses[start:], covs[start:], truth[start:],
                                                  strict=True)]
    position_rmse_m, heading_rmse_rad = _rmse(err[start:])
    return TrackMetrics(
        n_blocks=n, blocks_to_converge=start,
        position_rmse_m=position_rmse_m, heading_rmse_rad=heading_rmse_rad,
        share_within_tol=float(np.mean(err[:, 0] <= tol_m)),
        nees_mean=float(np.mean(nees_vals)),
        position_rmse_all_m=rmse_all[0], heading_rmse_all_rad=rmse_all[1],
    )


def _rmse(err: FloatArray) -> tuple[float, float]:
    """Root mean square of the (position m, heading rad) error rows (n, 2); NaN when n = 0."""
    if err.shape[0] == 0:
        return math.nan, math.nan
    rms = np.sqrt(np.mean(err**2, axis=0))
    return float(rms[0]), float(rms[1])


TRACK_STATUSES = ("converged", "uncertain", "lost")
"""The per-block status of a track (CLI track CSV), most confident first."""

STATUS_REASONS = ("", "unexplained", "misfit", "no_echo", "outside_coverage", "rivals",
                  "spread", "confirming", "jump_held", "reconfirming", "rival_doubt",
                  "open_map")
"""Why a particle filter's block is not ``converged`` (:attr:`PoseEstimate.reason`):
``unexplained`` lost, blocks in a row the estimate does not explain; ``misfit`` this block
not explained; ``no_echo`` the block heard nothing; ``outside_coverage`` the estimate lies
where the map has no evidence; ``rivals`` a symmetric twin or another place explains the
blocks as well (the modes hold them); ``spread`` the set is not one compact mode;
``confirming`` a global start waiting for agreeing blocks; ``jump_held`` an estimate far
from dead reckoning waiting for the blocks to prefer it; ``reconfirming`` after a misfit;
``rival_doubt`` a place elsewhere explained the recent blocks better (or, after a global
start, as well); ``open_map`` a global start on a map with an open wall end; ``""``
converged (or no reason given)."""


def track_status(estimate: PoseEstimate) -> str:
    """The status of one block, :attr:`PoseEstimate.status`: :func:`summarize` sets
    ``converged`` / ``uncertain`` from the set's shape; the particle filter refines it with
    the map's coverage and (echo model) how well the estimate explains the block, which is
    what can say ``lost``."""
    return estimate.status
