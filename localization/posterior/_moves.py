"""emcee ensembles of the pose posterior: starting walkers, moves and convergence checks.

Step 3 of :mod:`localization.posterior`: walkers drawn from a mode's grid cells or from a
particle cloud (never a single point, emcee issue 423), the move mixture DEMove 0.8 + snooker 0.2
with a corrected :class:`SnookerMove` (emcee's own DESnookerMove is biased), and a run extended
until the kept chain is >= ``tau_multiple`` integrated autocorrelation times or a step cap.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator
from typing import Any

import emcee
import numpy as np

from localization.posterior._grid import GridModes, GridPosterior, _step
from localization.posterior._records import ChainRun, PosteriorSettings
from localization.posterior._window import NDIM, FloatArray, _unwrap_about
from mapping.angles import mean_resultant


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
    return _unwrap_about(pts, mean_resultant(pts[:, 2], None)[0])


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
    c = mean_resultant(particles[:, 2], w)[0]
    pts = _unwrap_about(particles[rng.choice(w.size, size=n_walkers, p=w / w.sum())], c)
    if jitter is None:
        jitter = np.maximum(0.05 * pts.std(axis=0), [1e-3, 1e-3, math.radians(0.1)])
    return pts + rng.normal(size=pts.shape) * jitter


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

    Why not ``emcee.moves.DESnookerMove``: in emcee 3.0.0-3.1.6 (all releases so far) it
    scales e by
    ``1 / sqrt(|x - z|)`` instead of ``1 / |x - z|`` (the step then depends on the distance
    to z, so the proposal is not symmetric) and uses ``(d - 1) / 2`` for the Jacobian. On a
    3-D Gaussian alone it samples about 0.4 times the true variance, and in the 0.8/0.2 mixture
    about 0.92 times (``tests/test_posterior.py`` keeps both numbers as a regression check).
    The bias depends on the target's scale (checked independently: 0.39x the variance at sd
    0.1, 0.80x at sd 1, in 3-D); upstream fixed it in dfm/emcee PR #531, unreleased so far.
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
