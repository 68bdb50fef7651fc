"""Monte Carlo localization on the acoustic wall map (paper Fig. 1(b)).

Pure functions do the work (:func:`init_tracked`, :func:`init_global`, :func:`predict`,
:func:`weigh`, :func:`resample`, :func:`inject`); :class:`ParticleFilter` is a thin stateful
object that holds the arrays and calls them in order, one sonar block per :meth:`step`:

1. validate the block and odometry (nothing is mutated before this passes);
2. predict: sample the odometry motion model (:mod:`localization.motion`);
3. weigh: add the sensor log-likelihood (:mod:`localization.sensor`), normalize by
   log-sum-exp, and update the augmented-MCL averages ``w_slow``/``w_fast``
   (Thrun et al., *Probabilistic Robotics*, Table 8.3);
4. summarize the weighted set (:mod:`localization.estimate`); while the status is
   ``converged`` (echo model) the reported pose and covariance come from a Gaussian that
   follows the mode and is refined on each block's echoes (:mod:`localization.refine`);
5. resample systematically when ESS < ``resample_ess_fraction * n``, replacing a share
   ``max(0, 1 - e^t w_fast / w_slow)`` (threshold t) of particles by fresh poses drawn
   over the free space (candidates importance-weighted by the current block, i.e. sensor
   resetting) so a
   kidnapped robot is found again; optionally adapting the count (KLD sampling, Fox 2003).

The augmented-MCL averages are kept on the *geometric* mean likelihood of the set, i.e.
exponential averages of the prior-weighted mean log-likelihood ``beta * E[rho - 1]``
(:func:`weigh`), not on Thrun's arithmetic mean ``E[exp(beta (rho - 1))]``. At the sharp
beta an honest covariance needs (~100-300), the arithmetic mean of one block is set by its
single best particle and swings by 10-25 nats from block to block with the number of walls
in view; an average of such values is pinned to its largest past term, so ``w_fast``
drifted 0.65 nats per block below ``w_slow`` during ordinary tracking (measured on the
benchmark's pillar and L-room runs) and injection fired on a well-tracked robot, where
poses at the room's symmetric images then won. The threshold is set in correlation units
(``inject_threshold_rho``) so that it does not depend on beta.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterable, Iterator, Mapping
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.stats import norm

from localization import motion, refine, resampling
from localization.estimate import PoseEstimate, default_start_cov, summarize
from localization.motion import MotionNoise
from localization.particle_filter import _rivals
from localization.particle_filter._config import FilterConfig
from localization.particle_filter._rivals import Rivals, twin_evidence
from localization.sensor import (
    Explanation,
    Measurement,
    SensorTables,
    echo_proposals,
    explanation,
    log_likelihood,
    pose_log_likelihood,
    predicted_echoes,
    prepare_measurement,
    score_poses,
    symmetric_poses,
    uniform_free_poses,
)
from mapping.angles import wrap_angle
from mapping.heatmap import HeatMap

FloatArray = NDArray[np.float64]
STATE_FORMAT = "omnisonar-pf-state-1"


# ---- pure functions ----------------------------------------------------------------------
def init_tracked(pose: FloatArray, cov: FloatArray, n: int,
                 rng: np.random.Generator) -> FloatArray:
    """``n`` poses drawn from a Gaussian around ``pose`` (3,) with covariance ``cov`` (3, 3)."""
    pose = np.asarray(pose, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    if pose.shape != (3,) or not np.all(np.isfinite(pose)):
        raise ValueError(f"pose must be 3 finite numbers (x_m, y_m, heading_rad), got {pose}")
    if cov.shape != (3, 3) or not np.all(np.isfinite(cov)) or not np.allclose(cov, cov.T):
        raise ValueError("cov must be a finite symmetric 3x3 matrix")
    if np.linalg.eigvalsh(cov).min() < -1e-12:
        raise ValueError("cov must be positive semi-definite")
    out = rng.multivariate_normal(pose, cov, size=n, method="eigh")
    out[:, 2] = wrap_angle(out[:, 2])
    return out


def init_global(tables: SensorTables, n: int, rng: np.random.Generator) -> FloatArray:
    """``n`` poses uniform over the free cells of the map, headings uniform."""
    out = uniform_free_poses(tables, n, rng)
    out[:, 2] = wrap_angle(out[:, 2])
    return out


def predict(poses: FloatArray, speed_m_s: float, yaw_rate_rad_s: float, dt_s: float,
            noise: MotionNoise, rng: np.random.Generator) -> FloatArray:
    """Prediction step: :func:`localization.motion.predict`."""
    return motion.predict(poses, speed_m_s, yaw_rate_rad_s, dt_s, noise, rng)


def weigh(log_w: FloatArray, poses: FloatArray, tables: SensorTables,
          measurement: Measurement, min_ess_fraction: float = 0.0,
          z_rand: float | None = None) -> tuple[FloatArray, float, float]:
    """Measurement update.

    The likelihood is floored relative to the best particle (:func:`log_likelihood` with
    ``rho_ref`` = the set's best correlation), so one block changes weight ratios by at most
    ``1 / z_rand`` (``z_rand`` overrides the sensor's floor); tempered by
    :func:`temper_to_ess` when ``min_ess_fraction`` > 0.
    Returns the normalized log-weights, the augmented-MCL statistic (the prior-weighted
    mean log-likelihood ``beta * E[rho - 1]`` of the set, the log of its geometric mean
    likelihood, see the module docstring; ``-inf`` when no particle is on the map), and
    the tempering scale applied (1 = the full likelihood).
    """
    rho = score_poses(tables, measurement, poses)
    finite = np.isfinite(rho)
    ref = float(np.max(rho[finite])) if finite.any() else 1.0
    cfg = tables.config if z_rand is None else dataclasses.replace(tables.config, z_rand=z_rand)
    ll = log_likelihood(rho, cfg, ref)
    scale = temper_to_ess(log_w, ll, min_ess_fraction * log_w.size) if min_ess_fraction else 1.0
    new, _ = resampling.normalize_log_weights(log_w + scale * ll)
    if not finite.any():
        return new, -np.inf, scale
    prior = np.exp(log_w[finite] - resampling.log_sum_exp(log_w[finite]))
    stat = tables.config.beta * float(np.sum(prior * (rho[finite] - 1.0)))
    return new, stat, scale


def temper_to_ess(log_w: FloatArray, ll: FloatArray, min_ess: float,
                  iterations: int = 30) -> float:
    """Largest ``s`` in (0, 1] with ``ESS(log_w + s * ll) >= min_ess`` (1 if the full
    update keeps it).

    A likelihood much sharper than the particle set's spread (a global start, a wide
    prior, a symmetric room where two modes share the few particles near their cores)
    would otherwise leave a handful of particles to carry all the weight, and the split
    of weight between equally good modes would be decided by which mode happened to hold
    the luckiest particle. Applying only the share ``s`` of the block's log-likelihood
    (likelihood tempering, as in progressive correction, Oudjane and Musso 2000) keeps
    ``min_ess`` particles; the rest of that block's information is not used, so the
    reported covariance is wider than the full update's, never narrower.

    With equal prior weights (as after resampling) the ESS is non-increasing in ``s``
    (``d log ESS / ds = 2 (E_w[ll] - E_w2[ll]) <= 0``), so bisection finds the largest such
    scale; with unequal prior weights it finds a scale at which the ESS crosses
    ``min_ess``. If even ``s -> 0`` leaves fewer than ``min_ess`` (the prior itself is
    degenerate) the smallest scale (1e-6) is returned.
    """
    def ess(s: float) -> float:
        # (sum w)^2 / sum w^2 of the unnormalized weights, shifted by their maximum
        a = log_w + s * ll
        e = np.exp(a - np.max(a))
        return float(np.sum(e) ** 2 / np.sum(e * e))

    if not np.all(np.isfinite(ll)) or ess(1.0) >= min_ess:
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        if ess(mid) >= min_ess:
            lo = mid
        else:
            hi = mid
    return max(lo, 1e-6)


def resample(poses: FloatArray, log_w: FloatArray, rng: np.random.Generator,
             n_out: int | None = None) -> tuple[FloatArray, FloatArray]:
    """Systematic resampling; returns the new poses and uniform log-weights."""
    idx = resampling.systematic_resample(np.exp(log_w - log_w.max()), rng, n_out)
    n = idx.shape[0]
    return poses[idx].copy(), np.full(n, -math.log(n))


def inject(poses: FloatArray, n_inject: int, tables: SensorTables,
           measurement: Measurement | None, candidates: int,
           rng: np.random.Generator) -> FloatArray:
    """Replace ``n_inject`` random particles by poses drawn over the free space.

    With a ``measurement``, ``candidates * n_inject`` uniform poses are scored and the
    injected ones are drawn among them in proportion to their likelihood.
    """
    if n_inject <= 0:
        return poses
    out = poses.copy()
    slots = rng.choice(poses.shape[0], size=n_inject, replace=False)
    if measurement is None or candidates == 1:
        out[slots] = init_global(tables, n_inject, rng)
        return out
    cand = init_global(tables, candidates * n_inject, rng)
    ll = pose_log_likelihood(tables, measurement, cand, floor=True)
    pick = resampling.systematic_resample(np.exp(ll - ll.max()), rng, n_inject)
    out[slots] = cand[rng.permutation(pick)]
    return out


def propose(poses: FloatArray, n_replace: int, tables: SensorTables, measurement: Measurement,
            candidates: int, rng: np.random.Generator,
            gate: tuple[FloatArray, float, float] | None = None) -> FloatArray:
    """Replace ``n_replace`` random particles by poses that explain the block: ``candidates``
    times as many :func:`~localization.sensor.echo_proposals` are scored and the replacements
    drawn among them in proportion to their (floored) likelihood.

    ``gate = (pose, radius_m, radius_rad)`` keeps only proposals that close to ``pose`` (an
    anchored filter's local re-seed); with none inside it the particles stay as they are.
    """
    return propose_slots(poses, n_replace, tables, measurement, candidates, rng, gate)[0]


def propose_slots(poses: FloatArray, n_replace: int, tables: SensorTables,
                  measurement: Measurement, candidates: int, rng: np.random.Generator,
                  gate: tuple[FloatArray, float, float] | None = None
                  ) -> tuple[FloatArray, NDArray[np.int64]]:
    """:func:`propose`, also returning the indices of the replaced particles."""
    none = np.zeros(0, dtype=np.int64)
    n_replace = min(int(n_replace), poses.shape[0])
    if n_replace <= 0:
        return poses, none
    out = poses.copy()
    slots = rng.choice(poses.shape[0], size=n_replace, replace=False)
    cand = echo_proposals(tables, measurement, candidates * n_replace, rng)
    ll = pose_log_likelihood(tables, measurement, cand, floor=True)
    ll = np.where(np.isfinite(ll), ll, -np.inf)
    if gate is not None:
        centre, radius_m, radius_rad = gate
        near = ((np.hypot(cand[:, 0] - centre[0], cand[:, 1] - centre[1]) <= radius_m)
                & (np.abs(wrap_angle(cand[:, 2] - centre[2])) <= radius_rad))
        ll = np.where(near, ll, -np.inf)
        if not np.isfinite(ll).any():
            return poses, none
    if not np.isfinite(ll).any():
        out[slots] = init_global(tables, n_replace, rng)
        return out, slots.astype(np.int64)
    pick = resampling.systematic_resample(np.exp(ll - ll.max()), rng, n_replace)
    out[slots] = cand[rng.permutation(pick)]
    return out, slots.astype(np.int64)


def jumped(previous: FloatArray | None, estimate: FloatArray, speed_m_s: float,
           yaw_rate_rad_s: float, dt_s: float, gate_m: float, gate_rad: float) -> bool:
    """Whether ``estimate`` lies farther than the gate from where odometry (dead reckoning)
    carried the ``previous`` estimate (None: no previous estimate, no jump)."""
    if previous is None or not np.all(np.isfinite(previous)):
        return False
    pred = motion.predict_mean(previous, speed_m_s, yaw_rate_rad_s, dt_s)
    return beyond_gates(estimate, pred, gate_m, gate_rad)


def beyond_gates(a: FloatArray, b: FloatArray, gate_m: float, gate_rad: float) -> bool:
    """Whether poses ``a`` and ``b`` lie farther apart than ``gate_m`` or ``gate_rad``."""
    d = math.hypot(float(a[0] - b[0]), float(a[1] - b[1]))
    return d > gate_m or abs(float(wrap_angle(a[2] - b[2]))) > gate_rad


def block_fit(tables: SensorTables, measurement: Measurement, pose: FloatArray) -> float:
    """Echo model: how well ``pose`` explains the block, the mean of the share of measured
    peaks explained and the share of expected echoes heard (:func:`explanation`), in [0, 1]."""
    return fit_of(explanation(tables, measurement,
                              np.asarray(pose, dtype=np.float64).reshape(1, 3)))


def fit_of(ex: Explanation) -> float:
    """The fit of :func:`block_fit` from a one-pose :class:`Explanation`."""
    return float(0.5 * (ex.explained[0] + ex.heard[0]))


def block_status(converged: bool, covered: bool, misfits: int, lost_after: int,
                 heard_any: bool = True) -> str:
    """The honest status of one block.

    ``lost`` after ``lost_after`` unexplained blocks in a row; ``uncertain`` after one, when
    the set is not one compact mode, when the estimate is outside the map's coverage, or
    when the block heard nothing (no evidence of where the robot is); ``converged``
    otherwise.
    """
    if misfits >= lost_after:
        return "lost"
    if misfits > 0 or not converged or not covered or not heard_any:
        return "uncertain"
    return "converged"


def status_reason(converged: bool, rivals: bool, covered: bool, misfits: int,
                  lost_after: int, heard_any: bool = True) -> str:
    """Why :func:`block_status` gives the status it gives (one of
    :data:`~localization.estimate.STATUS_REASONS`, the first that applies in its order):
    ``unexplained`` (lost: ``lost_after`` blocks in a row), ``misfit`` (this block not
    explained), ``no_echo``, ``outside_coverage``, ``rivals`` (a symmetric twin or another
    place explains the blocks as well), ``spread`` (the set is not one compact mode), ``""``
    (converged)."""
    if misfits >= lost_after:
        return "unexplained"
    if misfits > 0:
        return "misfit"
    if not heard_any:
        return "no_echo"
    if not covered:
        return "outside_coverage"
    if rivals:
        return "rivals"
    if not converged:
        return "spread"
    return ""


def contradicts(pose: FloatArray, cov: FloatArray, reckoned: tuple[FloatArray, FloatArray],
                config: FilterConfig) -> bool:
    """Whether an estimate (pose, cov) contradicts the dead-reckoned ``reckoned`` (mean,
    covariance): beyond the anchor gates and more than 4 sigma (Mahalanobis) from it."""
    mean, rc = reckoned
    far = beyond_gates(pose, mean, config.anchor_gate_m, math.radians(config.anchor_gate_deg))
    return far and refine.mahalanobis(mean, rc, pose, cov) > 4.0


def hold_jump(pose: FloatArray, cov: FloatArray,
              reckoned: tuple[FloatArray, FloatArray] | None, dwell: int,
              config: FilterConfig, evidence: float | None = None,
              far: bool | None = None, counted: bool = True
              ) -> tuple[str, tuple[FloatArray, FloatArray] | None, int]:
    """The status of a block the filter would call ``converged``, against dead reckoning.

    ``reckoned``: the last converged estimate carried by the odometry (mean, covariance).
    An estimate that :func:`contradicts` it is ``uncertain`` for ``jump_dwell_blocks``
    blocks (counted in ``dwell``), then accepted, but only once ``evidence`` (the blocks'
    accumulated log-likelihood of the estimate over the best pose near the dead-reckoned
    one, :func:`reckoned_evidence`; None: not known, the time rule alone) reaches
    ``kidnap_prior_nats``: a jump to a look-alike that explains the blocks no better than
    where the odometry puts the robot (a map missing walls there) is never accepted.
    ``far``: :func:`contradicts` when the caller has computed it. ``counted``: whether the
    block was evidence at all (:func:`reckoned_evidence`); one that was not (the map silent
    where the odometry puts the robot) neither advances the count nor ends the hold, so a
    jump is believed only after ``jump_dwell_blocks`` blocks the map could judge, not after
    a few informative blocks and a long silence. Returns the status, the dead-reckoned pose
    to keep and the new count."""
    if reckoned is None or config.jump_dwell_blocks == 0:
        return "converged", reckoned, 0
    if not (contradicts(pose, cov, reckoned, config) if far is None else far):
        return "converged", reckoned, 0
    if not counted:
        return "uncertain", reckoned, dwell
    if dwell + 1 >= config.jump_dwell_blocks and (
            evidence is None or evidence >= config.kidnap_prior_nats):
        return "converged", reckoned, 0
    return "uncertain", reckoned, dwell + 1


def reckoned_evidence(tables: SensorTables, measurement: Measurement, ll_estimate: float,
                      reckoned: tuple[FloatArray, FloatArray], gap: float, memory: float,
                      min_echoes: int = 0, heard_max: float = 1.0, missed_min: float = 0.0
                      ) -> tuple[float, FloatArray, float, bool]:
    """Evidence (nats) for a held jump: ``memory * gap + ll(estimate) - ll(best)``, ``best``
    the pose near the dead-reckoned one that explains the block best (a shrinking stencil
    from its mean, steps of its standard deviations clipped to 2-25 cm and 1-10 deg).

    Where the map predicts fewer than ``min_echoes`` specular echoes at ``best`` (a place
    the map has no walls for: beyond its mapped walls' ends or out of their range), the
    block is no evidence: that the pose explains it badly says the map is silent there, not
    that the robot was carried away; the evidence is ``memory * gap``. Likewise where at
    least ``heard_max`` of the echoes the map predicts at ``best`` are heard, or fewer than
    ``missed_min`` of its specular echoes go unheard (the map and the odometry agree; what
    ``best`` leaves unexplained, or does not hear, are walls the map lacks).
    Returns the evidence, the best pose, its log-likelihood and whether the block counted
    (False: the map silent there, the evidence only remembered)."""
    sd = np.sqrt(np.maximum(np.diag(reckoned[1]), 0.0))
    step = (float(np.clip(sd[0], 0.02, 0.25)), float(np.clip(sd[1], 0.02, 0.25)),
            float(np.clip(sd[2], math.radians(1.0), math.radians(10.0))))
    best, ll = _rivals.refine_poses(tables, measurement, reckoned[0][None, :], step, rounds=3)
    remembered = memory * gap, best[0], float(ll[0]), False
    if min_echoes > 0 or heard_max < 1.0 or missed_min > 0.0:
        n_best = map_echoes(tables, measurement.speed_m_s, best[0])
        if n_best < min_echoes:
            return remembered
        if heard_max < 1.0 or missed_min > 0.0:
            heard = float(explanation(tables, measurement, best).heard[0])
            if heard >= heard_max or n_best * (1.0 - heard) < missed_min:
                return remembered
    return memory * gap + ll_estimate - float(ll[0]), best[0], float(ll[0]), True


def map_echoes(tables: SensorTables, speed_m_s: float, pose: FloatArray) -> int:
    """How many specular (first-order) echoes the map's walls give at ``pose`` within the
    sensor's range: how much the map can say about a block heard there."""
    if tables.walls.n == 0:
        return 0
    b, _ = predicted_echoes(tables, speed_m_s, np.asarray(pose, dtype=np.float64)[None, :],
                            parallel=False)
    k = int(b.count[0])
    return int(np.sum(b.order[0, :k] == 1))


def confirm_start(pose: FloatArray, cov: FloatArray,
                  candidate: tuple[FloatArray, FloatArray] | None, count: int,
                  config: FilterConfig, fit: float = math.nan
                  ) -> tuple[str, tuple[FloatArray, FloatArray] | None, int]:
    """The status of a global start's block the filter would call ``converged`` before its
    first convergence is confirmed (``FilterConfig.confirm_blocks``).

    ``candidate``: the previous such estimate carried by the odometry (None at the first);
    ``count``: how many agreeing ones led to it. An estimate that does not
    :func:`contradict <contradicts>` the candidate adds one, one that does starts again at
    one; one whose block ``fit`` (echo model; NaN: not known) is below
    ``FilterConfig.confirm_fit`` does not count (it keeps the count when it agrees, else
    starts again at zero). Returns ``converged`` once the count reaches ``confirm_blocks``
    (then the count is 0), else ``uncertain`` with this estimate as the next candidate."""
    agree = candidate is not None and not contradicts(pose, cov, candidate, config)
    if math.isfinite(fit) and fit < config.confirm_fit:
        count = count if agree else 0
    else:
        count = count + 1 if agree else 1
    if count >= config.confirm_blocks:
        return "converged", candidate, 0
    return "uncertain", (np.array(pose, dtype=np.float64), np.array(cov, dtype=np.float64)), count


def open_world(tables: SensorTables, config: FilterConfig) -> bool:
    """Whether a global start may never be reported ``converged`` on ``tables``: a map
    built from runs (not :attr:`~localization.sensor.SensorTables.complete`) with an open
    wall end (:attr:`~localization.sensor.SensorTables.open_ends`) has free space it knows
    nothing of, where the robot may stand hearing walls that look like mapped ones, and
    ``FilterConfig.open_map_global`` is ``"uncertain"``."""
    return (config.open_map_global == "uncertain" and not tables.complete
            and tables.open_ends > 0)


def reconfirm(candidate: bool, fit: float, count: int, config: FilterConfig) -> int:
    """The count of :attr:`ParticleFilter.recovery` after one more block while the filter
    re-confirms after a misfit (``FilterConfig.reconfirm_blocks``): ``count``
    blocks in a row led to it; this one adds one when it is a ``candidate`` (the filter
    would call it converged before any hold on a jump) with a ``fit`` (NaN: not known) of
    at least ``FilterConfig.confirm_fit``, else the count starts again at 0. The status may
    be ``converged`` once the count reaches ``reconfirm_blocks``."""
    good = candidate and not (math.isfinite(fit) and fit < config.confirm_fit)
    return count + 1 if good else 0


def kld_count(poses: FloatArray, config: FilterConfig) -> int:
    """Particles needed for KL error ``kld_epsilon`` at confidence ``1 - kld_delta``."""
    keys = np.stack([np.floor(poses[:, 0] / config.kld_bin_m),
                     np.floor(poses[:, 1] / config.kld_bin_m),
                     np.floor((poses[:, 2] + np.pi) / config.kld_bin_rad)], axis=1)
    k = np.unique(keys, axis=0).shape[0]
    if k <= 1:
        return config.n_min
    z = float(norm.ppf(1 - config.kld_delta))
    a = 2.0 / (9.0 * (k - 1))
    n = (k - 1) / (2 * config.kld_epsilon) * (1 - a + math.sqrt(a) * z) ** 3
    return int(np.clip(math.ceil(n), config.n_min, config.n_max))


# ---- the stateful object -------------------------------------------------------------------
class ParticleFilter:
    """Particle filter over (x_m, y_m, heading_rad) on one wall map.

    Parameters
    ----------
    tables : SensorTables
        Lookup tables of the map (:func:`localization.sensor.build_tables`); shared, read-only.
    config : FilterConfig
    rng : numpy.random.Generator
        Owned by the filter from now on (its state is part of :meth:`state_dict`).
    pose, cov : array-like, optional
        Tracked initialization (3,), (3, 3). Without them the filter starts global.
    """

    def __init__(self, tables: SensorTables, config: FilterConfig, rng: np.random.Generator,
                 pose: FloatArray | None = None, cov: FloatArray | None = None) -> None:
        self.tables = tables
        self.config = config
        self.rng = rng
        self.log_w_slow = -np.inf
        self.log_w_fast = -np.inf
        self.n_steps = 0
        self.misfits = 0
        self.fresh = False
        self.anchored = False
        self.last_pose: FloatArray | None = None
        self.twin_gap = np.zeros(0)
        self.rivals = Rivals.none()
        self.track: tuple[FloatArray, FloatArray] | None = None
        self.scatter = refine.Scatter.none()
        self.reckoned: tuple[FloatArray, FloatArray] | None = None
        self.dwell = 0
        self.jump_gap = 0.0
        self.confirmed = False
        self.recovery = -1
        self.global_start = False
        if pose is None:
            self.reset_global()
        else:
            self.reset_tracked(pose, default_start_cov()
                               if cov is None else cov)

    # -- initialization
    def reset_global(self) -> None:
        """Uniform over the free space (global localization), ``global_oversample`` times
        ``n_particles`` until the first resampling."""
        n = self.config.n_particles * self.config.global_oversample
        self.poses = init_global(self.tables, n, self.rng)
        self.log_w = np.full(n, -math.log(n))
        self.log_w_slow = self.log_w_fast = -np.inf
        self.converged = False
        self.misfits = 0
        self.fresh = True
        self.anchored = False
        self.last_pose = None
        self.rivals = Rivals.none()
        self.track = None
        self.reckoned = None
        self.dwell = 0
        self.jump_gap = 0.0
        self.confirmed = False
        self.recovery = -1
        self.global_start = True

    def reset_tracked(self, pose: FloatArray, cov: FloatArray) -> None:
        """Gaussian around a known pose."""
        n = self.config.n_particles
        self.poses = init_tracked(pose, cov, n, self.rng)
        self.log_w = np.full(n, -math.log(n))
        self.log_w_slow = self.log_w_fast = -np.inf
        self.misfits = 0
        self.fresh = False
        self.anchored = True
        self.last_pose = None
        self.rivals = Rivals.none()
        self.track = None
        c = np.asarray(cov, dtype=np.float64)
        self.reckoned = (np.asarray(pose, dtype=np.float64).copy(), c.copy())
        self.dwell = 0
        self.jump_gap = 0.0
        self.confirmed = True
        self.global_start = False
        self.recovery = -1
        cl = self.config.cluster
        self.converged = bool(math.sqrt(max(c[0, 0] + c[1, 1], 0.0)) <= cl.converged_std_m
                              and math.sqrt(max(c[2, 2], 0.0)) <= cl.converged_std_rad)

    @property
    def n_particles(self) -> int:
        """Current particle count."""
        return int(self.poses.shape[0])

    # -- one block
    def step(self, heat_map: HeatMap | None, speed_m_s: float, yaw_rate_rad_s: float,
             dt_s: float) -> PoseEstimate:
        """Advance by one block.

        Parameters
        ----------
        heat_map : HeatMap or None
            The block's heat map; None (a silent or missing block) predicts only.
        speed_m_s, yaw_rate_rad_s : float
            Odometry of the motion since the previous block's midpoint.
        dt_s : float
            Time since the previous block's midpoint (0 for the first block).

        Raises
        ------
        ValueError
            Bad heat map or odometry; the filter state is then unchanged.
        """
        motion.odometry_increment(speed_m_s, yaw_rate_rad_s, dt_s)   # validates
        meas = None if heat_map is None else prepare_measurement(heat_map, self.tables.config)
        rng_state = self.rng.bit_generator.state
        try:
            return self._commit(meas, speed_m_s, yaw_rate_rad_s, dt_s)
        except BaseException:
            self.rng.bit_generator.state = rng_state
            raise

    def _commit(self, meas: Measurement | None, speed_m_s: float, yaw_rate_rad_s: float,
                dt_s: float) -> PoseEstimate:
        cfg = self.config
        poses = predict(self.poses, speed_m_s, yaw_rate_rad_s, dt_s, cfg.motion, self.rng)
        log_w = self.log_w
        scale = 1.0
        slow, fast = self.log_w_slow, self.log_w_fast
        echo = meas is not None and meas.model == "echo"
        if echo and self.fresh and meas is not None and meas.n_peaks and cfg.relocalize:
            # a global start's first block: half the set becomes poses explaining it
            poses = propose(poses, poses.shape[0] // 2, self.tables, meas,
                            cfg.proposal_candidates, self.rng)
        if meas is not None:
            z = None if self.converged else cfg.z_rand_unconverged
            log_w, log_avg, scale = weigh(log_w, poses, self.tables, meas,
                                          cfg.min_ess_fraction, z)
            if not np.isfinite(log_avg):
                pass
            elif not np.isfinite(slow):
                slow = fast = log_avg
            else:
                slow += cfg.alpha_slow * (log_avg - slow)
                fast += cfg.alpha_fast * (log_avg - fast)
        ess = resampling.effective_sample_size(log_w)
        estimate = summarize(
            poses, log_w, cfg.cluster, ess=ess,
            direction_observable=bool(meas is not None and meas.direction_observable),
            updated=meas is not None, model="none" if meas is None else meas.model,
            likelihood_scale=scale)
        misfits, fit = self.misfits, math.nan
        gate_rad = math.radians(cfg.anchor_gate_deg)
        anchored = self.anchored and not jumped(self.last_pose, estimate.pose, speed_m_s,
                                                yaw_rate_rad_s, dt_s, cfg.anchor_gate_m,
                                                gate_rad)
        rivals = np.zeros((0, 3))
        alive = rivals
        doubts = 0
        at_estimate: Explanation | None = None
        twin_gap = self.twin_gap
        held = _rivals.advance(self.rivals, speed_m_s, yaw_rate_rad_s, dt_s)
        doubt_only = not (anchored or cfg.rival_tie_particles)   # unanchored ties: status only
        if echo and meas is not None and meas.n_peaks:
            at_estimate = explanation(self.tables, meas, estimate.pose.reshape(1, 3))
            fit = fit_of(at_estimate)
            misfits = misfits + 1 if fit < cfg.fit_threshold else 0
            # a symmetric twin is a rival only when the prior does not rule it out: a tracked
            # start followed without a jump pins the robot to one side of the symmetry
            twins = (np.zeros((0, 3)) if anchored
                     else symmetric_poses(self.tables.symmetries, estimate.pose))
            if twins.shape[0]:
                twin_gap = twin_evidence(self.tables, meas, estimate.pose, twins,
                                         self.twin_gap, cfg.twin_memory)
                rivals = twins[twin_gap < cfg.twin_margin_nats]
            # poses elsewhere that explain the blocks as well (better, while anchored);
            # unanchored, near ties join too (rival_admit_nats): a global start must know
            # of every place that explains the blocks about as well
            params = (cfg.rival_params if anchored
                      else dataclasses.replace(cfg.rival_params,
                                               pair_share=cfg.rival_pair_share_unanchored,
                                               admit_nats=cfg.rival_admit_nats))
            held = _rivals.update(self.tables, meas, estimate.pose, held, params,
                                  self.rng, float(at_estimate.log_likelihood[0]))
            found = _rivals.active(held, anchored, cfg.rival_margin_nats, cfg.twin_margin_nats)
            doubts = _rivals.active(held, anchored, min(cfg.rival_doubt_nats,
                                                        cfg.rival_margin_nats),
                                    cfg.twin_margin_nats).shape[0]
            # ties only doubt (unless rival_tie_particles): particles go to rivals that
            # explained the recent blocks better by more than rival_doubt_nats
            fed = (_rivals.active(held, True, min(cfg.rival_doubt_nats,
                                                  cfg.rival_margin_nats), 0.0)
                   if doubt_only else found)
            # data-driven rivals get particles only when the filter may re-localize
            alive = np.vstack([rivals, fed]) if cfg.relocalize else rivals
            # ties that only doubt leave the filter's own logic (confirmation, holds,
            # refinement) alone: they make the status uncertain at the end (``doubts``)
            rivals = np.vstack([rivals, fed])
        covered = bool(self.tables.covered(estimate.pose[None, :2])[0])
        heard_any = meas is None or meas.n_peaks > 0 or not echo
        status = block_status(estimate.converged and rivals.shape[0] == 0, covered, misfits,
                              cfg.lost_after, heard_any)
        reason = status_reason(estimate.converged, rivals.shape[0] > 0, covered, misfits,
                               cfg.lost_after, heard_any)
        candidate = status
        reckoned = (None if self.reckoned is None else
                    refine.predict(self.reckoned[0], self.reckoned[1], speed_m_s,
                                   yaw_rate_rad_s, dt_s, cfg.motion))
        dwell, confirmed = self.dwell, self.confirmed
        jump_gap, back = 0.0, np.zeros((0, 3))
        # the particles' estimate against dead reckoning from the last confirmed convergence:
        # far from it, the blocks must prefer it by the kidnap prior before it is believed
        evidence: float | None = None
        counted = True
        far = confirmed and reckoned is not None and contradicts(estimate.pose, estimate.cov,
                                                                 reckoned, cfg)
        if far and reckoned is not None:
            if echo and meas is not None and at_estimate is not None:
                evidence, best, _, counted = reckoned_evidence(
                    self.tables, meas, float(at_estimate.log_likelihood[0]), reckoned,
                    self.jump_gap, cfg.rival_memory, cfg.min_map_echoes,
                    # a complete map claims every wall: every block counts there
                    1.0 if self.tables.complete else cfg.jump_heard_max,
                    0.0 if self.tables.complete else cfg.jump_missed_min)
                if evidence < cfg.kidnap_prior_nats:
                    back = best[None, :]   # the dead-reckoned pose explains as well: keep it
            jump_gap = self.jump_gap if evidence is None else evidence
        if status == "converged" and confirmed:
            status, reckoned, dwell = hold_jump(estimate.pose, estimate.cov, reckoned, dwell,
                                                cfg, evidence, far, counted)
            reason = reason if status == "converged" else "jump_held"
        elif status == "converged":
            status, reckoned, dwell = confirm_start(estimate.pose, estimate.cov, reckoned,
                                                    dwell, cfg, fit)
            confirmed = status == "converged"
            reason = reason if confirmed else "confirming"
        # after a misfit, convergence must be re-confirmed by well-explained blocks
        # (a jump the hold accepted moves the dead-reckoned pose all the same)
        accepted = status == "converged"
        recovery = self.recovery
        if misfits > 0 and cfg.reconfirm_blocks > 0 and echo:
            recovery = 0
        elif recovery >= 0 and meas is not None:
            recovery = reconfirm(candidate == "converged", fit, recovery, cfg)
            if status == "converged" and recovery >= cfg.reconfirm_blocks:
                recovery = -1
            elif status == "converged":
                status, reason = "uncertain", "reconfirming"
        if status == "converged" and doubts:
            # a place elsewhere explains the recent blocks better, by less than a kidnap
            # needs (or, unanchored, as well): the estimate stands, the status says it is in
            # doubt
            status, reason = "uncertain", "rival_doubt"
        relocalized = self.global_start or (cfg.open_map_relocalized and not anchored)
        if status == "converged" and relocalized and open_world(self.tables, cfg):
            # a global start on an open map, or a tracked filter that lost its track and
            # found a place again: the robot may stand where the map knows nothing; the
            # filter goes on as confirmed, the status says so
            status, reason = "uncertain", "open_map"
        estimate = dataclasses.replace(estimate, status=status, fit=fit, covered=covered,
                                       reason=reason)
        particles_pose = estimate.pose
        if (cfg.report_reckoned and far and reckoned is not None and status != "converged"
                and self.tables.config.model == "echo" and jump_gap < cfg.kidnap_prior_nats):
            # a jump the blocks do not prefer (a map missing walls here, a look-alike): the
            # answer is where the odometry puts the robot, with its growing covariance
            estimate = dataclasses.replace(
                estimate, pose=reckoned[0].copy(), cov=reckoned[1].copy(), reckoned=True,
                covered=bool(self.tables.covered(reckoned[0][None, :2])[0]))
        reseed = echo and cfg.relocalize and misfits > 0 and meas is not None
        low_ess = ess < cfg.resample_ess_fraction * poses.shape[0]
        if back.shape[0] and cfg.relocalize:
            # a held jump the blocks do not prefer: particles go back where the odometry says
            alive = np.vstack([alive, back])
        # rivals that only put the status in doubt do not move the particles
        moved = alive.shape[0] if doubt_only else rivals.shape[0]
        if meas is not None and (reseed or moved or low_ess or back.shape[0]):
            n_out = kld_count(poses, cfg) if cfg.kld else cfg.n_particles
            poses, log_w = resample(poses, log_w, self.rng, n_out)
            p_inject = 0.0
            if cfg.augmented and not echo and np.isfinite(slow) and np.isfinite(fast):
                gap = fast - slow + self.tables.config.beta * cfg.inject_threshold_rho
                p_inject = max(0.0, 1.0 - math.exp(min(gap, 0.0)))
            p_inject = min(p_inject, cfg.max_inject_fraction)
            n_inject = int(self.rng.binomial(n_out, p_inject)) if p_inject > 0 else 0
            if n_inject:
                poses = inject(poses, n_inject, self.tables, meas, cfg.inject_candidates,
                               self.rng)
            if alive.shape[0]:
                # keep the other explanations alive as particles (the modes are reported)
                k = int(round(cfg.twin_fraction * n_out))
                if k:
                    slots = self.rng.choice(n_out, size=k, replace=False)
                    poses = poses.copy()
                    poses[slots] = alive[self.rng.integers(0, alive.shape[0], size=k)]
                    if anchored and cfg.kidnap_prior_nats > 0:
                        # while anchored a rival is a kidnap hypothesis: its particles carry
                        # the prior odds of one and must out-explain the track to take over
                        log_w = log_w.copy()
                        log_w[slots] -= cfg.kidnap_prior_nats
                        log_w, _ = resampling.normalize_log_weights(log_w)
            if reseed and meas is not None:
                share = (1.0 if misfits >= cfg.reseed_after
                         else min(2.0 * cfg.reseed_fraction, 1.0) if misfits >= cfg.lost_after
                         else cfg.reseed_fraction)
                if anchored and misfits < cfg.lost_after:
                    # near the estimate: a poor block is no reason to look elsewhere
                    poses = propose(poses, int(round(share * n_out)), self.tables, meas,
                                    cfg.proposal_candidates, self.rng,
                                    (estimate.pose, cfg.anchor_gate_m, gate_rad))
                elif anchored:
                    # lost while anchored: the whole map, at the prior odds of a kidnap,
                    # and the tracked hypothesis keeps the rest of the particles
                    share = min(share, 2.0 * cfg.reseed_fraction)
                    poses, slots = propose_slots(poses, int(round(share * n_out)),
                                                 self.tables, meas, cfg.proposal_candidates,
                                                 self.rng)
                    if slots.size and cfg.kidnap_prior_nats > 0:
                        log_w = log_w.copy()
                        log_w[slots] -= cfg.kidnap_prior_nats
                        log_w, _ = resampling.normalize_log_weights(log_w)
                else:
                    poses = propose(poses, int(round(share * n_out)), self.tables, meas,
                                    cfg.proposal_candidates, self.rng)
        track, scatter, report = self._refine(estimate, meas, echo, speed_m_s,
                                              yaw_rate_rad_s, dt_s, accepted)
        if track is not None and report:
            estimate = dataclasses.replace(estimate, pose=track[0].copy(), cov=track[1].copy(),
                                           refined=True)
        self.poses, self.log_w = poses, log_w
        self.log_w_slow, self.log_w_fast = slow, fast
        self.track, self.scatter = track, scatter
        self.n_steps += 1
        self.misfits = misfits
        self.anchored = anchored
        self.last_pose = (particles_pose if estimate.reckoned else estimate.pose).copy()
        if accepted:
            reckoned = (estimate.pose.copy(), estimate.cov.copy())   # the reported pose
        self.reckoned, self.dwell, self.confirmed = reckoned, dwell, confirmed
        self.recovery = recovery
        self.jump_gap = jump_gap
        self.twin_gap = twin_gap
        self.rivals = held
        if meas is not None:
            self.converged = estimate.converged and misfits == 0
            self.fresh = self.fresh and not (echo and meas.n_peaks)
        return estimate

    def _refine(self, estimate: PoseEstimate, meas: Measurement | None, echo: bool,
                speed_m_s: float, yaw_rate_rad_s: float, dt_s: float, accepted: bool
                ) -> tuple[tuple[FloatArray, FloatArray] | None, refine.Scatter, bool]:
        """The Gaussian refinement of a converged mode (:mod:`localization.refine`): carried
        by the odometry, restarted from the particles' mode when the two disagree, updated
        with the block. ``accepted``: the block passed every rule for ``converged`` but
        re-confirmation (which gates the status, not the estimate). Returns the Gaussian to
        keep (None when not accepted or the model is not the echo model), the residuals kept
        and whether the Gaussian is reported for this block (not when it could not explain
        the block: the particles' mode is reported, the Gaussian kept as predicted)."""
        rc = self.config.refine
        if not (rc.enabled and echo and accepted):
            return None, self.scatter, False
        track = self.track
        if track is not None:
            track = refine.predict(track[0], track[1], speed_m_s, yaw_rate_rad_s, dt_s,
                                   self.config.motion)
            if refine.mahalanobis(track[0], track[1], estimate.pose,
                                  estimate.cov) > rc.reset_mahalanobis:
                track = None
        if track is None:
            track = (estimate.pose.copy(), estimate.cov.copy())
        if meas is None or not meas.n_peaks:
            return track, self.scatter, True
        sigma_r, sigma_c = refine.noise(self.tables, meas, self.scatter, rc)
        scale_sd = (refine.speed_scale_sd(speed_m_s, yaw_rate_rad_s, dt_s, self.config.motion)
                    if rc.speed_scale else 0.0)
        out = refine.update(self.tables, meas, track[0], track[1], sigma_r, sigma_c, rc,
                            scale_sd, refine.model_cov(yaw_rate_rad_s, dt_s, rc))
        if not out.ok:
            return track, self.scatter, False
        return ((out.mean, out.cov),
                self.scatter.add(out.range_residuals_m, out.cos_residuals, rc.scatter_memory),
                True)

    # -- checkpointing
    def state_dict(self) -> dict[str, NDArray[Any]]:
        """The whole filter state as numpy arrays (``np.savez``-able without pickle)."""
        return {
            "format": np.array(STATE_FORMAT),
            "config": np.array(self.config.to_json()),
            "poses": self.poses.copy(),
            "log_w": self.log_w.copy(),
            "log_w_slow_fast": np.array([self.log_w_slow, self.log_w_fast]),
            "n_steps": np.array(self.n_steps, dtype=np.int64),
            "converged": np.array(self.converged),
            "misfits": np.array(self.misfits, dtype=np.int64),
            "fresh": np.array(self.fresh),
            "anchored": np.array(self.anchored),
            "last_pose": (np.full(3, np.nan) if self.last_pose is None
                          else np.asarray(self.last_pose, dtype=np.float64).copy()),
            "twin_gap": np.asarray(self.twin_gap, dtype=np.float64).copy(),
            "rival_poses": self.rivals.poses.copy(),
            "rival_gap": self.rivals.gap.copy(),
            "track_mean": (np.full(3, np.nan) if self.track is None else self.track[0].copy()),
            "track_cov": (np.full((3, 3), np.nan) if self.track is None
                          else self.track[1].copy()),
            "scatter_range_m": self.scatter.range_m.copy(),
            "scatter_cos": self.scatter.cos.copy(),
            "reckoned_mean": (np.full(3, np.nan) if self.reckoned is None
                              else self.reckoned[0].copy()),
            "reckoned_cov": (np.full((3, 3), np.nan) if self.reckoned is None
                             else self.reckoned[1].copy()),
            "dwell": np.array(self.dwell, dtype=np.int64),
            "confirmed": np.array(self.confirmed),
            "global_start": np.array(self.global_start),
            "recovery": np.array(self.recovery, dtype=np.int64),
            "jump_gap": np.array(self.jump_gap, dtype=np.float64),
            "rng": np.array(json.dumps(self.rng.bit_generator.state)),
        }

    @classmethod
    def from_state_dict(cls, state: Mapping[str, NDArray[Any]],
                        tables: SensorTables) -> ParticleFilter:
        """Rebuild a filter from :meth:`state_dict` output on the same map's tables."""
        if str(state.get("format", "")) != STATE_FORMAT:
            raise ValueError(f"state 'format' must be {STATE_FORMAT!r}")
        poses = np.array(state["poses"], dtype=np.float64)
        log_w = np.array(state["log_w"], dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != 3 or log_w.shape != (poses.shape[0],):
            raise ValueError("state 'poses' must be (n, 3) and 'log_w' (n,)")
        rng_state = json.loads(str(state["rng"]))
        rng = np.random.Generator(getattr(np.random, rng_state["bit_generator"])())
        rng.bit_generator.state = rng_state
        pf = cls.__new__(cls)
        pf.tables = tables
        pf.config = FilterConfig.from_json(str(state["config"]))
        pf.rng = rng
        pf.poses, pf.log_w = poses, log_w
        pf.log_w_slow, pf.log_w_fast = (float(v) for v in state["log_w_slow_fast"])
        pf.n_steps = int(state["n_steps"])
        pf.converged = bool(state["converged"]) if "converged" in state else False
        pf.misfits = int(state["misfits"]) if "misfits" in state else 0
        pf.fresh = bool(state["fresh"]) if "fresh" in state else False
        pf.anchored = bool(state["anchored"]) if "anchored" in state else False
        last = (np.array(state["last_pose"], dtype=np.float64) if "last_pose" in state
                else np.full(3, np.nan))
        pf.last_pose = last if last.shape == (3,) and np.all(np.isfinite(last)) else None
        pf.twin_gap = (np.array(state["twin_gap"], dtype=np.float64) if "twin_gap" in state
                       else np.zeros(0))
        pf.rivals = Rivals.none()
        if "rival_poses" in state and "rival_gap" in state:
            rp = np.array(state["rival_poses"], dtype=np.float64).reshape(-1, 3)
            rg = np.array(state["rival_gap"], dtype=np.float64).reshape(-1)
            if rp.shape[0] != rg.shape[0]:
                raise ValueError("state 'rival_poses' (k, 3) and 'rival_gap' (k,) must agree")
            pf.rivals = Rivals(rp, rg)
        pf.scatter = refine.Scatter.none()
        pf.track = _gaussian_of(state, "track")
        pf.reckoned = _gaussian_of(state, "reckoned")
        pf.dwell = int(state["dwell"]) if "dwell" in state else 0
        # checkpoints from before the confirmation: a filter that had converged is confirmed
        pf.confirmed = (bool(state["confirmed"]) if "confirmed" in state
                        else pf.reckoned is not None)
        pf.jump_gap = float(state["jump_gap"]) if "jump_gap" in state else 0.0
        pf.global_start = bool(state["global_start"]) if "global_start" in state else False
        pf.recovery = int(state["recovery"]) if "recovery" in state else -1
        if "scatter_range_m" in state and "scatter_cos" in state:
            pf.scatter = refine.Scatter(
                np.array(state["scatter_range_m"], dtype=np.float64).reshape(-1),
                np.array(state["scatter_cos"], dtype=np.float64).reshape(-1))
        return pf


def _gaussian_of(state: Mapping[str, NDArray[Any]], name: str
                 ) -> tuple[FloatArray, FloatArray] | None:
    """The Gaussian ``<name>_mean`` (3,), ``<name>_cov`` (3, 3) of a state dict (None when
    absent, as in older checkpoints, or stored as NaN)."""
    if f"{name}_mean" not in state or f"{name}_cov" not in state:
        return None
    mean = np.array(state[f"{name}_mean"], dtype=np.float64).reshape(-1)
    cov = np.array(state[f"{name}_cov"], dtype=np.float64)
    if mean.shape != (3,) or cov.shape != (3, 3):
        raise ValueError(f"state '{name}_mean' must be (3,) and '{name}_cov' (3, 3)")
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
        return None
    return mean, cov


# ---- running a filter over a run -----------------------------------------------------------
class Steppable(Protocol):
    """Anything with the filters' ``step`` (ParticleFilter, GridFilter)."""

    def step(self, heat_map: HeatMap | None, speed_m_s: float, yaw_rate_rad_s: float,
             dt_s: float) -> PoseEstimate: ...


def block_odometry(speed_m_s: FloatArray, yaw_rate_rad_s: FloatArray, t_s: FloatArray,
                   block_s: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Odometry from each block's midpoint to the next: mean speed and yaw rate of the two
    blocks and the time between midpoints (0 for the first block)."""
    v = np.asarray(speed_m_s, dtype=np.float64)
    w = np.asarray(yaw_rate_rad_s, dtype=np.float64)
    mid = np.asarray(t_s, dtype=np.float64) + 0.5 * block_s
    v_step = np.concatenate([[v[0]], 0.5 * (v[1:] + v[:-1])])
    w_step = np.concatenate([[w[0]], 0.5 * (w[1:] + w[:-1])])
    dt = np.concatenate([[0.0], np.diff(mid)])
    return v_step, w_step, dt


def run_filter(filt: Steppable, heat_maps: Iterable[HeatMap | None], speed_m_s: FloatArray,
               yaw_rate_rad_s: FloatArray, t_s: FloatArray, block_s: float
               ) -> Iterator[PoseEstimate]:
    """Step ``filt`` through a run's blocks, yielding one estimate per block (a generator:
    the caller decides what to keep). A None heat map predicts only."""
    v, w, dt = block_odometry(speed_m_s, yaw_rate_rad_s, t_s, block_s)
    for k, hm in enumerate(heat_maps):
        yield filt.step(hm, float(v[k]), float(w[k]), float(dt[k]))
