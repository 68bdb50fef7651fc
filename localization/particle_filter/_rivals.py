"""Rival hypotheses: poses far from the estimate that explain the blocks as well or better.

A particle filter only weighs the poses its particles hold. After a kidnap along a corridor,
or once it has settled on a look-alike, nothing in its own set says that a pose elsewhere
explains the sonar better: the estimate's fit can stay above any fixed threshold (measured:
a robot carried 4.8 m along the long corridor kept a fit of 0.62-0.69 and status
``converged`` for 10 blocks, because only the end wall's echo, now out of range, was
missing). This module keeps a few such rivals next to the filter, each block:

1. the rivals of the previous block move by dead reckoning (:func:`advance`);
2. :func:`~localization.sensor.echo_proposals` draws poses that hear the block's strongest
   echoes as specular echoes of a wall; the best few far from the estimate are refined
   (:func:`refine_best`), and those that explain the block at least as well as the estimate
   join (:func:`admit`, de-duplicated, at most ``max_rivals``);
3. every rival is refined on the block (:func:`refine_poses`) and its evidence updated:
   ``gap = memory * gap + ll(estimate) - ll(rival)`` (echo log-likelihoods, nats; the twin
   rule of :func:`twin_evidence` applied to data-driven poses, with a longer memory so a
   weak but lasting preference adds up);
4. rivals the estimate clearly beats (``gap > drop_nats``), rivals that merged into the
   estimate and rivals off the free space are dropped (:func:`prune`).

:func:`active` says which rivals count against the estimate: with a prior that rules other
places out (a tracked start followed without a jump, *anchored*), only rivals that explained
the recent blocks *better* by a margin; without one, also the ties (a symmetric room,
a corridor whose ends are out of range: the honest answer there is "uncertain").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization import motion
from localization.sensor import Measurement, SensorTables, echo_proposals, explanation
from mapping.angles import wrap_angle

FloatArray = NDArray[np.float64]

_STENCIL = np.stack(np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0],
                                indexing="ij"), axis=-1).reshape(-1, 3)
_CENTRE = int(np.flatnonzero(~_STENCIL.any(axis=1))[0])
_RING = np.flatnonzero(_STENCIL.any(axis=1))


@dataclass(frozen=True)
class Rivals:
    """Rival poses (k, 3) and the discounted evidence for the estimate over each (k,), nats
    (negative: the rival explained the recent blocks better)."""

    poses: FloatArray
    gap: FloatArray

    @staticmethod
    def none() -> Rivals:
        """No rival."""
        return Rivals(np.zeros((0, 3)), np.zeros(0))

    @property
    def n(self) -> int:
        """Rivals held."""
        return int(self.poses.shape[0])


@dataclass(frozen=True)
class RivalParams:
    """How rivals are found and weighed (the :class:`FilterConfig` fields ``rival_*``).

    Attributes
    ----------
    proposals : int
        Echo proposals scored per block (0: no rivals).
    max_rivals : int
        Rivals kept.
    separation_m, separation_rad : float
        A rival is farther than this from the estimate (either one); closer ones merged.
    memory : float
        Forgetting factor of the evidence per block.
    drop_nats : float
        A rival whose evidence gap exceeds this is dropped.
    refine_top : int
        The best this many proposals beyond the separation from the estimate and the rivals
        are refined (:func:`refine_poses`) before they are compared with the estimate: a
        proposal is a few cm and degrees off the place it stands for, and the estimate it
        is compared with is the filter's mode, itself on its peak (0: compared as drawn).
    pair_share : float
        Share of the proposals that explain two peaks at once
        (:func:`~localization.sensor.pair_proposals`).
    admit_nats : float
        A proposal joins when it explains the block at least as well as the estimate less
        this (nats; 0: at least as well).
    """

    proposals: int
    max_rivals: int
    separation_m: float
    separation_rad: float
    memory: float
    drop_nats: float
    refine_top: int = 0
    pair_share: float = 0.0
    admit_nats: float = 0.0


def refine_poses(tables: SensorTables, measurement: Measurement, poses: FloatArray,
                 step: tuple[float, float, float] = (0.04, 0.04, math.radians(3.0)),
                 rounds: int = 4) -> tuple[FloatArray, FloatArray]:
    """Each pose (k, 3) moved to the best echo log-likelihood on a shrinking 3x3x3 stencil
    (``rounds`` halvings of ``step``); returns the poses and their log-likelihoods."""
    cur = np.asarray(poses, dtype=np.float64).copy()
    # the stencil holds its centre, so the first round scores the poses as they are
    best = (explanation(tables, measurement, cur).log_likelihood
            if cur.shape[0] and rounds <= 0 else np.zeros(0))
    h = np.asarray(step, dtype=np.float64)
    for r in range(rounds):
        if cur.shape[0] == 0:
            break
        cand = (cur[:, None, :] + _STENCIL[None] * h).reshape(-1, 3)
        if r == 0:
            ll = explanation(tables, measurement, cand).log_likelihood.reshape(cur.shape[0], -1)
        else:   # the centre is the last round's pick (cur + 0 == cur): its score is best
            ring = cand.reshape(cur.shape[0], -1, 3)[:, _RING].reshape(-1, 3)
            ll = np.empty((cur.shape[0], _STENCIL.shape[0]))
            ll[:, _RING] = explanation(tables, measurement, ring).log_likelihood.reshape(
                cur.shape[0], -1)
            ll[:, _CENTRE] = best
        pick = ll.argmax(axis=1)
        cur = cand.reshape(cur.shape[0], -1, 3)[np.arange(cur.shape[0]), pick]
        best = ll[np.arange(cur.shape[0]), pick]
        h = h / 2.0
    cur[:, 2] = wrap_angle(cur[:, 2])
    return cur, np.asarray(best, dtype=np.float64)


def twin_evidence(tables: SensorTables, measurement: Measurement, pose: FloatArray,
                  twins: FloatArray, gap: FloatArray, memory: float) -> FloatArray:
    """Evidence (nats) for ``pose`` over each of its symmetric ``twins`` (k, 3), accumulated
    with forgetting: ``memory * gap + ll(pose) - ll(twin)`` (echo log-likelihoods of this
    block). A symmetric room's twin explains every block alike, so its evidence stays near
    0 until the walls in view break the symmetry; ``gap`` of another length restarts at 0."""
    ex = explanation(tables, measurement, np.vstack([pose[None, :], twins]))
    now = ex.log_likelihood[0] - ex.log_likelihood[1:]
    prev = gap if gap.shape == now.shape else np.zeros_like(now)
    return np.asarray(memory * prev + now)


def advance(rivals: Rivals, speed_m_s: float, yaw_rate_rad_s: float, dt_s: float) -> Rivals:
    """The rivals moved by the odometry (dead reckoning, no noise)."""
    if rivals.n == 0:
        return rivals
    rot1, trans, rot2 = motion.odometry_increment(speed_m_s, yaw_rate_rad_s, dt_s)
    return Rivals(motion.apply_increment(rivals.poses, rot1, trans, rot2), rivals.gap)


def far_from(poses: FloatArray, pose: FloatArray, separation_m: float,
             separation_rad: float) -> NDArray[np.bool_]:
    """Whether each pose (k, 3) is farther than the separation from ``pose`` (either)."""
    d = np.hypot(poses[:, 0] - pose[0], poses[:, 1] - pose[1])
    return (d > separation_m) | (np.abs(wrap_angle(poses[:, 2] - pose[2])) > separation_rad)


def admit(candidates: FloatArray, ll: FloatArray, ll_estimate: float, held: FloatArray,
          room: int, separation_m: float, separation_rad: float) -> FloatArray:
    """Up to ``room`` candidates (k, 3), best first, that explain the block at least as well
    as the estimate (``ll >= ll_estimate``) and lie beyond the separation from every pose
    in ``held`` (m, 3; the estimate and the rivals) and from each other."""
    order = np.argsort(-ll, kind="stable")
    taken: list[FloatArray] = []
    for i in order:
        if len(taken) >= room or not ll[i] >= ll_estimate:
            break
        others = np.vstack([held, *taken]) if taken else held
        if np.all(far_from(others, candidates[i], separation_m, separation_rad)):
            taken.append(candidates[i][None, :])
    return np.vstack(taken) if taken else np.zeros((0, 3))


def refine_best(tables: SensorTables, measurement: Measurement, candidates: FloatArray,
                ll: FloatArray, held: FloatArray, top: int, separation_m: float,
                separation_rad: float) -> tuple[FloatArray, FloatArray]:
    """``candidates`` (k, 3) and their log-likelihoods ``ll`` (k,) with the best ``top`` of
    those beyond the separation from every pose in ``held`` (m, 3) moved to their refined
    poses and log-likelihoods (:func:`refine_poses`, steps of 4 cm and 3 deg halved
    twice); the others as given."""
    far = np.ones(candidates.shape[0], dtype=bool)
    for h in held:
        far &= far_from(candidates, h, separation_m, separation_rad)
    idx = np.flatnonzero(far)
    idx = idx[np.argsort(-ll[idx], kind="stable")[:top]]
    if idx.size == 0:
        return candidates, ll
    poses, best = refine_poses(tables, measurement, candidates[idx],
                               step=(0.04, 0.04, math.radians(3.0)), rounds=3)
    out, out_ll = candidates.copy(), np.asarray(ll, dtype=np.float64).copy()
    out[idx], out_ll[idx] = poses, best
    return out, out_ll


def prune(tables: SensorTables, rivals: Rivals, estimate: FloatArray,
          params: RivalParams) -> Rivals:
    """Rivals kept: on the free space, beyond the separation from the estimate and from
    every better rival, evidence gap at most ``drop_nats``; best (lowest gap) first, at most
    ``max_rivals``."""
    keep = (tables.free_at(rivals.poses[:, :2])
            & far_from(rivals.poses, estimate, params.separation_m, params.separation_rad)
            & (rivals.gap <= params.drop_nats))
    idx = np.flatnonzero(keep)[np.argsort(rivals.gap[keep], kind="stable")]
    out: list[int] = []
    for i in idx:
        if len(out) >= params.max_rivals:
            break
        if not out or np.all(far_from(rivals.poses[out], rivals.poses[i], params.separation_m,
                                      params.separation_rad)):
            out.append(int(i))
    return Rivals(rivals.poses[out], rivals.gap[out])


def update(tables: SensorTables, measurement: Measurement, estimate: FloatArray,
           rivals: Rivals, params: RivalParams, rng: np.random.Generator,
           ll_estimate: float | None = None) -> Rivals:
    """One block of rival tracking (steps 2-4 of the module docstring; ``rivals`` already
    advanced). ``ll_estimate``: the estimate's echo log-likelihood of this block when the
    caller has it (computed here otherwise). A block without peaks leaves the rivals as they
    are."""
    if params.proposals <= 0 or measurement.n_peaks == 0 or tables.walls.n == 0:
        return rivals
    ll_est = (float(explanation(tables, measurement, estimate[None, :]).log_likelihood[0])
              if ll_estimate is None else float(ll_estimate))
    cand = echo_proposals(tables, measurement, params.proposals, rng,
                          pair_share=params.pair_share)
    ll_cand = explanation(tables, measurement, cand).log_likelihood
    held = np.vstack([estimate[None, :], rivals.poses])
    if params.refine_top > 0 and cand.shape[0]:
        cand, ll_cand = refine_best(tables, measurement, cand, ll_cand, held,
                                    params.refine_top, params.separation_m,
                                    params.separation_rad)
    new = admit(cand, ll_cand, ll_est - params.admit_nats, held, params.max_rivals,
                params.separation_m, params.separation_rad)
    poses = np.vstack([rivals.poses, new])
    prev = np.concatenate([params.memory * rivals.gap, np.zeros(new.shape[0])])
    poses, ll = refine_poses(tables, measurement, poses,
                             step=(0.015, 0.015, math.radians(1.5)), rounds=2)
    return prune(tables, Rivals(poses, prev + ll_est - ll), estimate, params)


def active(rivals: Rivals, anchored: bool, better_nats: float, tie_nats: float) -> FloatArray:
    """The rivals (k, 3) that count against the estimate: evidence gap below
    ``-better_nats`` (better) when anchored, below ``tie_nats`` (as good) otherwise."""
    limit = -better_nats if anchored else tie_nats
    return rivals.poses[rivals.gap < limit]
