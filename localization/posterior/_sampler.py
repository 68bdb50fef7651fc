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

Modules: :mod:`localization.posterior_window` (poses, odometry, window likelihood, prior),
:mod:`localization.posterior_grid` (grid posterior, modes), :mod:`localization.posterior_moves`
(walkers, moves, ensembles), :mod:`localization.posterior_diagnostics` (comparisons, HPD, cloud
calibration), :mod:`localization.posterior_records` (settings, results). Every public name of
those modules is importable from here.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.posterior._diagnostics import (
    compare_with_grid,
    hpd_thresholds,
    summarize_samples,
)
from localization.posterior._grid import (
    GridModes,
    GridPosterior,
    _axis,
    _cell_labels,
    find_grid_modes,
    full_turn_headings,
    grid_log_posterior,
    local_grid,
    mode_heading_center,
)
from localization.posterior._moves import (
    run_ensemble,
    walkers_from_cloud,
    walkers_from_grid,
)
from localization.posterior._records import (
    ChainRun,
    GridComparison,
    ModeSummary,
    PosteriorResult,
    PosteriorSettings,
    Progress,
)
from localization.posterior._window import (
    NDIM,
    FloatArray,
    LogLikelihood,
    PosePrior,
    _unwrap_about,
)
from mapping.angles import circular_std_of_resultant, pose_difference, wrap_angle

# ---- log posterior ---------------------------------------------------------------------


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


# ---- the pipeline ---------------------------------------------------------------------


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

        p0 = _unwrap_about(_start_walkers(grid, modes, k, cloud, cloud_labels, s, rng), c)
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


def _start_walkers(
    grid: GridPosterior, modes: GridModes, k: int,
    cloud: tuple[FloatArray, FloatArray | None] | None,
    cloud_labels: NDArray[np.int64] | None, s: PosteriorSettings, rng: np.random.Generator,
) -> FloatArray:
    """Mode ``k``'s walkers: from the cloud when it holds ``n_walkers`` particles there."""
    if cloud is not None and cloud_labels is not None and \
            int(np.sum(cloud_labels == k)) >= s.n_walkers:
        sel = cloud_labels == k
        w = None if cloud[1] is None else np.asarray(cloud[1], dtype=np.float64)[sel]
        return walkers_from_cloud(np.asarray(cloud[0])[sel], w, s.n_walkers, rng)
    return walkers_from_grid(grid, modes, k, s.n_walkers, rng)


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
                d = pose_difference(stats[j][0], stats[i][0])
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
            heading_resultant_length=r, heading_circular_std_rad=circular_std_of_resultant(r),
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
