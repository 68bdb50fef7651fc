"""Calibrating the sensor sharpness ``beta`` by the filter's NEES (issue 6).

A tempered likelihood ``exp(beta rho)`` treats each block as independent evidence; map
errors and the overlap between blocks make that optimistic, so beta is chosen per map from
tracked runs such that the particle filter's reported covariance is honest: the mean
normalized estimation error squared of the best mode (3 degrees of freedom) is 3.
:func:`calibrate_beta` runs the filter per candidate, :func:`pick_beta` interpolates.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.estimate import default_start_cov, track_metrics
from localization.particle_filter import FilterConfig, ParticleFilter, run_filter
from localization.sensor import SensorTables
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
    def from_run(cls, run: Run) -> CalibrationRun:
        """Heat maps of every block of a tracked run (:func:`mapping.heatmap.heatmap_of_run`),
        its odometry and its tracked poses as the truth.

        Raises
        ------
        ValueError
            The run has no tracked pose in its first block (the filter starts there).
        """
        if not np.all(np.isfinite(run.pose[0])):
            raise ValueError("a calibration run needs a tracked pose in its first block")
        return cls(tuple(heatmap_of_run(run, k) for k in range(run.n_blocks)),
                   run.speed_m_s, run.yaw_rate_rad_s, run.t_s, run.config.block_s, run.pose)


@dataclass(frozen=True)
class BetaCalibration:
    """Result of :func:`calibrate_beta`.

    Attributes
    ----------
    beta : float
        The chosen sharpness.
    betas : tuple of float
        Candidates tried, ascending.
    nees_mean : tuple of float
        Mean NEES over the runs that stayed tracked, per candidate (NaN: every run lost).
    lost_runs : tuple of int
        Runs (x seeds) that left 10 cm / 10 deg at some block, per candidate.
    """

    beta: float
    betas: tuple[float, ...]
    nees_mean: tuple[float, ...]
    lost_runs: tuple[int, ...]


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
    b = np.asarray(betas, dtype=np.float64)
    q = np.asarray(nees_mean, dtype=np.float64)
    lost = np.asarray(lost_runs)
    if not (b.shape == q.shape == lost.shape) or b.ndim != 1 or b.size == 0:
        raise ValueError("betas, nees_mean and lost_runs must be 1-d of equal, nonzero length")
    if not np.all(b > 0) or not np.all(np.isfinite(b)):
        raise ValueError("betas must be finite and > 0")
    if not target_nees > 0:
        raise ValueError(f"target_nees must be > 0, got {target_nees}")
    ok = (lost == 0) & np.isfinite(q) & (q > 0)
    if not ok.any():
        raise ValueError("every beta candidate lost a run (or gave no NEES): nothing to pick")
    order = np.argsort(b[ok])
    bs = b[ok][order]
    lb, lq = np.log(bs), np.log(q[ok][order]) - math.log(target_nees)
    for i in range(lb.size - 1):
        if lq[i] <= 0.0 <= lq[i + 1] and lq[i + 1] > lq[i]:
            return float(math.exp(lb[i] + (lb[i + 1] - lb[i]) * -lq[i] / (lq[i + 1] - lq[i])))
    return float(bs[int(np.argmin(np.abs(lq)))])


def calibrate_beta(tables: SensorTables, runs: Sequence[CalibrationRun],
                   betas: Sequence[float], config: FilterConfig, rng: np.random.Generator,
                   prior_cov: FloatArray | None = None, n_seeds: int = 1,
                   target_nees: float = 3.0) -> BetaCalibration:
    """Pick the sensor sharpness ``beta`` that makes the reported covariance honest.

    For every candidate beta, the particle filter (``config``; ``tables`` with their beta
    replaced) tracks every run from a start drawn around its true first pose with
    ``prior_cov`` (default 10 cm / 10 deg), ``n_seeds`` times; the normalized estimation
    error squared of the best mode, ``e^T cov^-1 e`` (3 degrees of freedom, so 3 on average
    when the covariance is honest), is averaged over the blocks and runs. :func:`pick_beta`
    then interpolates the beta whose mean NEES is ``target_nees``.

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
    cand = sorted(float(b) for b in betas)
    seeds = rng.integers(0, 2**63 - 1, size=(len(cand), len(runs), n_seeds))
    nees_mean, lost = [], []
    for i, beta in enumerate(cand):
        tab = dataclasses.replace(tables, config=dataclasses.replace(tables.config, beta=beta))
        vals, n_lost = [], 0
        for j, run in enumerate(runs):
            for s in range(n_seeds):
                pf = ParticleFilter(tab, config, np.random.default_rng(int(seeds[i, j, s])),
                                    pose=run.truth[0], cov=cov)
                ests = list(run_filter(pf, run.heat_maps, run.speed_m_s, run.yaw_rate_rad_s,
                                       run.t_s, run.block_s))
                m = track_metrics(np.array([e.pose for e in ests]),
                                  np.array([e.cov for e in ests]), run.truth)
                if m.blocks_to_converge == 0:
                    vals.append(m.nees_mean)
                else:
                    n_lost += 1
        nees_mean.append(float(np.mean(vals)) if vals else math.nan)
        lost.append(n_lost)
    return BetaCalibration(beta=pick_beta(cand, nees_mean, lost, target_nees),
                           betas=tuple(cand), nees_mean=tuple(nees_mean), lost_runs=tuple(lost))
