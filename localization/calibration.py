"""Calibrating the sensor sharpness ``beta`` by the filter's NEES (issue 6).

A tempered likelihood ``exp(beta rho)`` treats each block as independent evidence; map
errors and the overlap between blocks make that optimistic, so beta is chosen per map from
tracked runs such that the particle filter's reported covariance is honest: the mean
normalized estimation error squared of the best mode (3 degrees of freedom) is 3.
:func:`calibrate_beta` runs the filter per candidate, :func:`pick_beta` interpolates; when
no candidate brackets the target, :func:`widen_candidate` proposes the next one beyond the ends
(:func:`search_beta` tries up to ``max_widen`` of them).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.estimate import default_start_cov, track_metrics
from localization.particle_filter import FilterConfig, ParticleFilter, block_fit, run_filter
from localization.sensor import SensorConfig, SensorTables, heatmap_run, prepare_measurement
from mapping.heatmap import HeatMap, heatmap_of_run
from mapping.run import Run

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class CalibrationRun:
    """One run with ground truth, ready for :func:`calibrate_beta`.

    Attributes
    ----------
    heat_maps : tuple of HeatMap or None
        One per block (None predicts only).
    speed_m_s, yaw_rate_rad_s, t_s : ndarray (n,)
        Odometry and block start times, as in :class:`mapping.runfile.Run`.
    block_s : float
        Block duration.
    truth : ndarray (n, 3)
        True pose at each block midpoint.
    """

    heat_maps: tuple[HeatMap | None, ...]
    speed_m_s: FloatArray
    yaw_rate_rad_s: FloatArray
    t_s: FloatArray
    block_s: float
    truth: FloatArray

    @classmethod
    def from_run(cls, run: Run, sensor: SensorConfig | None = None) -> CalibrationRun:
        """Heat maps of every block of a tracked run (:func:`mapping.heatmap.heatmap_of_run`,
        with the bank the sensor model ``sensor`` reads, :func:`localization.sensor.heatmap_run`;
        None: the run's own), its odometry and its tracked poses as the truth.

        Raises
        ------
        ValueError
            The run has no tracked pose in its first block (the filter starts there).
        """
        if not np.all(np.isfinite(run.pose[0])):
            raise ValueError("a calibration run needs a tracked pose in its first block")
        heard = run if sensor is None else heatmap_run(run, sensor)
        return cls(tuple(heatmap_of_run(heard, k) for k in range(run.n_blocks)),
                   run.speed_m_s, run.yaw_rate_rad_s, run.t_s, run.config.block_s, run.pose)


@dataclass(frozen=True)
class BetaCalibration:
    """Result of :func:`calibrate_beta`.

    Attributes
    ----------
    beta : float
        The chosen sharpness.
    betas : tuple of float
        Candidates tried, ascending (the given ones and any added by widening).
    nees_mean : tuple of float
        Mean NEES over the runs that stayed tracked, per candidate (NaN: every run lost).
    lost_runs : tuple of int
        Runs (x seeds) that left 10 cm / 10 deg at some block, per candidate.
    bracketed : bool
        Whether the target NEES lies between two candidates (:func:`brackets_target`), so
        ``beta`` is interpolated; False: ``beta`` is the nearest candidate, an end of the range.
    widened : tuple of float
        Candidates added beyond the given range because none bracketed the target, in the
        order they were tried (empty: the given candidates bracketed it, or widening was off).
    """

    beta: float
    betas: tuple[float, ...]
    nees_mean: tuple[float, ...]
    lost_runs: tuple[int, ...]
    bracketed: bool = True
    widened: tuple[float, ...] = ()


def _usable(betas: Sequence[float], nees_mean: Sequence[float], lost_runs: Sequence[int],
            target_nees: float) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]:
    """Validated ``(beta, log(NEES / target), NEES, usable)``, sorted by beta; a candidate is
    usable when it lost no run and its mean NEES is finite and > 0."""
    b = np.asarray(betas, dtype=np.float64)
    q = np.asarray(nees_mean, dtype=np.float64)
    lost = np.asarray(lost_runs)
    if not (b.shape == q.shape == lost.shape) or b.ndim != 1 or b.size == 0:
        raise ValueError("betas, nees_mean and lost_runs must be 1-d of equal, nonzero length")
    if not np.all(b > 0) or not np.all(np.isfinite(b)):
        raise ValueError("betas must be finite and > 0")
    if not target_nees > 0:
        raise ValueError(f"target_nees must be > 0, got {target_nees}")
    order = np.argsort(b, kind="stable")
    b, q, lost = b[order], q[order], lost[order]
    ok = (lost == 0) & np.isfinite(q) & (q > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        lq = np.log(q) - math.log(target_nees)
    return b, lq, q, ok


def _crossing(bs: FloatArray, lq: FloatArray) -> float | None:
    """The first upward crossing of 0 by ``lq`` (piecewise linear in log beta), or None."""
    lb = np.log(bs)
    for i in range(lb.size - 1):
        if lq[i] <= 0.0 <= lq[i + 1] and lq[i + 1] > lq[i]:
            return float(math.exp(lb[i] + (lb[i + 1] - lb[i]) * -lq[i] / (lq[i + 1] - lq[i])))
    return None


def pick_beta(betas: Sequence[float], nees_mean: Sequence[float], lost_runs: Sequence[int],
              target_nees: float = 3.0) -> float:
    """The sharpness whose mean NEES is ``target_nees``.

    Among the candidates with no lost run, the mean NEES is taken as piecewise linear in
    ``(log beta, log NEES)``; the first upward crossing of ``target_nees`` is returned (a
    sharper likelihood reports a tighter covariance, so NEES grows with beta). Without a
    crossing, the candidate whose NEES is nearest to the target in log ratio. (Under the
    earlier 5 % floor NEES peaked near beta 100 and never reached 3; with the default
    ``z_rand`` = 1e-3 it rises through 3 on the benchmark maps, see the README.)

    Raises
    ------
    ValueError
        Lengths differ, a beta is not > 0, or every candidate lost a run.
    """
    b, lq, _, ok = _usable(betas, nees_mean, lost_runs, target_nees)
    if not ok.any():
        raise ValueError("every beta candidate lost a run (or gave no NEES): nothing to pick")
    beta = _crossing(b[ok], lq[ok])
    return beta if beta is not None else float(b[ok][int(np.argmin(np.abs(lq[ok])))])


def brackets_target(betas: Sequence[float], nees_mean: Sequence[float],
                    lost_runs: Sequence[int], target_nees: float = 3.0) -> bool:
    """Whether :func:`pick_beta` interpolates: the usable candidates' mean NEES crosses
    ``target_nees`` upward between two of them, or one of them hits it exactly.

    Raises
    ------
    ValueError
        As :func:`pick_beta` for malformed input (every candidate lost: False).
    """
    b, lq, _, ok = _usable(betas, nees_mean, lost_runs, target_nees)
    return bool(ok.any()) and (_crossing(b[ok], lq[ok]) is not None
                               or bool(np.any(lq[ok] == 0.0)))


def widen_candidate(betas: Sequence[float], nees_mean: Sequence[float],
                    lost_runs: Sequence[int], target_nees: float = 3.0,
                    factor: float = 2.0) -> float | None:
    """The next candidate beyond the ends when none brackets ``target_nees``, or None.

    NEES grows with beta (:func:`pick_beta`), so when every usable candidate's mean NEES is
    below the target, the largest beta times ``factor``; when every one is above, the
    smallest divided by ``factor``. None when the candidates bracket the target already, when
    the end to widen from lost a run (a sharper, resp. blunter, likelihood is not expected to
    track better), when no candidate is usable, or when the NEES crosses the target only
    downward (widening would not find the upward crossing the rule looks for).

    Parameters
    ----------
    betas, nees_mean, lost_runs : sequence (n,)
        As for :func:`pick_beta`, in any order.
    target_nees : float
    factor : float
        > 1: the step beyond the ends, a ratio (2 doubles / halves).

    Raises
    ------
    ValueError
        As :func:`pick_beta`, or ``factor`` <= 1.
    """
    if not (math.isfinite(factor) and factor > 1.0):
        raise ValueError(f"factor must be finite and > 1, got {factor}")
    if brackets_target(betas, nees_mean, lost_runs, target_nees):
        return None
    b, lq, _, ok = _usable(betas, nees_mean, lost_runs, target_nees)
    if not ok.any():
        return None
    if ok[-1] and np.all(lq[ok] < 0.0):
        return float(b[-1] * factor)
    if ok[0] and np.all(lq[ok] > 0.0):
        return float(b[0] / factor)
    return None


def search_beta(evaluate: Callable[[float], tuple[float, int]], betas: Sequence[float],
                target_nees: float = 3.0, max_widen: int = 0,
                factor: float = 2.0) -> BetaCalibration:
    """Evaluate candidates, widen the range while none brackets the target, pick beta.

    Every candidate of ``betas`` is evaluated in ascending order; then, while
    :func:`widen_candidate` proposes one and fewer than ``max_widen`` were added, that one
    too. :func:`pick_beta` picks among all of them.

    Parameters
    ----------
    evaluate : callable
        ``beta -> (mean NEES, lost runs)`` (:func:`calibrate_beta` runs the filter).
    betas : sequence of float
        Candidates, finite and > 0.
    target_nees : float
    max_widen : int
        >= 0: at most this many candidates beyond the given range (0: none).
    factor : float
        Step of the widening (:func:`widen_candidate`).

    Returns
    -------
    BetaCalibration

    Raises
    ------
    ValueError
        Bad ``betas``, ``max_widen`` or ``factor``; every candidate lost a run.
    """
    if not betas or any(not (math.isfinite(b) and b > 0) for b in betas):
        raise ValueError("betas must be a nonempty sequence of finite values > 0")
    if max_widen < 0:
        raise ValueError(f"max_widen must be >= 0, got {max_widen}")
    if not (math.isfinite(factor) and factor > 1.0):
        raise ValueError(f"factor must be finite and > 1, got {factor}")
    tried = {float(b): evaluate(float(b)) for b in sorted(betas)}
    widened: list[float] = []

    def table() -> tuple[list[float], list[float], list[int]]:
        cand = sorted(tried)
        return cand, [tried[b][0] for b in cand], [tried[b][1] for b in cand]

    while len(widened) < max_widen:
        nxt = widen_candidate(*table(), target_nees, factor)
        if nxt is None:
            break
        tried[nxt] = evaluate(nxt)
        widened.append(nxt)
    cand, nees_mean, lost = table()
    return BetaCalibration(beta=pick_beta(cand, nees_mean, lost, target_nees),
                           betas=tuple(cand), nees_mean=tuple(float(q) for q in nees_mean),
                           lost_runs=tuple(int(n) for n in lost),
                           bracketed=brackets_target(cand, nees_mean, lost, target_nees),
                           widened=tuple(widened))


def calibrate_beta(tables: SensorTables, runs: Sequence[CalibrationRun],
                   betas: Sequence[float], config: FilterConfig, rng: np.random.Generator,
                   prior_cov: FloatArray | None = None, n_seeds: int = 1,
                   target_nees: float = 3.0, max_widen: int = 0,
                   widen_factor: float = 2.0) -> BetaCalibration:
    """Pick the sensor sharpness ``beta`` that makes the reported covariance honest.

    For every candidate beta, the particle filter (``config``; ``tables`` with their beta
    replaced) tracks every run from a start drawn around its true first pose with
    ``prior_cov`` (default 10 cm / 10 deg), ``n_seeds`` times; the normalized estimation
    error squared of the best mode, ``e^T cov^-1 e`` (3 degrees of freedom, so 3 on average
    when the covariance is honest), is averaged over the blocks and runs. :func:`pick_beta`
    then interpolates the beta whose mean NEES is ``target_nees``. When no candidate brackets
    the target, up to ``max_widen`` more are tried beyond the ends (:func:`search_beta`).

    Parameters
    ----------
    tables : SensorTables
        Tables of the map the runs are localized on.
    runs : sequence of CalibrationRun
        Runs with ground truth (held out from the map's own mapping runs).
    betas : sequence of float
        Candidates, > 0.
    config : FilterConfig
        Filter settings (particle count, motion noise) the beta is calibrated for.
    rng : numpy.random.Generator
        Source of the filters' generators.
    prior_cov : ndarray (3, 3), optional
    n_seeds : int
        Filter runs per run and candidate.
    target_nees : float
        3 for an honest 3-dof covariance.
    max_widen : int
        Candidates at most added beyond the given range (0, the default: none).
    widen_factor : float
        > 1: each added candidate is the largest times it or the smallest divided by it
        (:func:`widen_candidate`).

    Returns
    -------
    BetaCalibration
    """
    if not runs:
        raise ValueError("runs must hold at least one CalibrationRun")
    if n_seeds < 1:
        raise ValueError(f"n_seeds must be >= 1, got {n_seeds}")
    if any(not (math.isfinite(b) and b > 0) for b in betas) or not betas:
        raise ValueError("betas must be a nonempty sequence of finite values > 0")
    cov = (default_start_cov() if prior_cov is None
           else np.asarray(prior_cov, dtype=np.float64))
    # the given candidates' seeds are drawn up front (as before widening existed); each
    # added candidate draws its own afterwards
    seeds = list(rng.integers(0, 2**63 - 1, size=(len(betas), len(runs), n_seeds)))

    def evaluate(beta: float) -> tuple[float, int]:
        seed = seeds.pop(0) if seeds else rng.integers(0, 2**63 - 1, size=(len(runs), n_seeds))
        tab = dataclasses.replace(tables, config=dataclasses.replace(tables.config, beta=beta))
        vals, n_lost = [], 0
        for j, run in enumerate(runs):
            for s in range(n_seeds):
                pf = ParticleFilter(tab, config, np.random.default_rng(int(seed[j, s])),
                                    pose=run.truth[0], cov=cov)
                ests = list(run_filter(pf, run.heat_maps, run.speed_m_s, run.yaw_rate_rad_s,
                                       run.t_s, run.block_s))
                m = track_metrics(np.array([e.pose for e in ests]),
                                  np.array([e.cov for e in ests]), run.truth)
                if m.blocks_to_converge == 0:
                    vals.append(m.nees_mean)
                else:
                    n_lost += 1
        return (float(np.mean(vals)) if vals else math.nan), n_lost

    return search_beta(evaluate, betas, target_nees, max_widen, widen_factor)


@dataclass(frozen=True)
class FitCalibration:
    """Result of :func:`calibrate_fit_threshold`.

    Attributes
    ----------
    threshold : float
        The ``quantile`` of the block fit at the true pose (``FilterConfig.fit_threshold``).
    quantile : float
    fits : ndarray
        The fit at the true pose of every block used (with truth and at least one peak).
    """

    threshold: float
    quantile: float
    fits: FloatArray


def calibrate_fit_threshold(tables: SensorTables, runs: Sequence[CalibrationRun],
                            quantile: float = 0.01) -> FitCalibration:
    """How well the echo model explains blocks at the TRUE pose on tracked runs: the
    ``quantile`` of that fit is the threshold below which the filter calls a block
    unexplained (so about ``quantile`` of well-tracked blocks are flagged, and the status
    says ``uncertain`` for one of them; two in a row, ``lost``, happen at about its square).

    Raises
    ------
    ValueError
        ``tables`` not for the echo model, ``quantile`` outside (0, 0.5], or no usable block.
    """
    if tables.config.model != "echo":
        raise ValueError(f"tables must be for model 'echo', got {tables.config.model!r}")
    if not 0 < quantile <= 0.5:
        raise ValueError(f"quantile must be in (0, 0.5], got {quantile}")
    fits = []
    for run in runs:
        for hm, truth in zip(run.heat_maps, run.truth, strict=True):
            if hm is None or not np.all(np.isfinite(truth)):
                continue
            meas = prepare_measurement(hm, tables.config)
            if meas.n_peaks:
                fits.append(block_fit(tables, meas, truth))
    if not fits:
        raise ValueError("no block with truth and an echo peak to calibrate on")
    arr = np.asarray(fits)
    return FitCalibration(float(np.quantile(arr, quantile)), float(quantile), arr)
