"""Parameters of the particle filter (:class:`FilterConfig`), JSON round trip included.

Kept apart from :mod:`localization.particle_filter` (which re-exports it) so the filter
module holds the algorithm only; every field is documented with its unit and its measured
effect.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field

from localization.estimate import ClusterConfig
from localization.motion import MotionNoise
from localization.particle_filter._rivals import RivalParams
from localization.refine import RefineConfig


@dataclass(frozen=True)
class FilterConfig:
    """Particle filter parameters.

    Parameters
    ----------
    n_particles : int
        Particle count (the initial count when ``kld`` is on).
    resample_ess_fraction : float
        Resample when ESS falls below this fraction of the count.
    augmented : bool
        Augmented-MCL recovery (random injection) on.
    alpha_slow, alpha_fast : float
        Smoothing rates of the long- and short-term likelihood averages (per block).
    max_inject_fraction : float
        Cap on the share of particles replaced in one resampling.
    inject_threshold_rho : float
        Injection starts only when the short-term average of the set's mean correlation
        falls this far below the long-term one; with ``t = beta * inject_threshold_rho``
        nats the share injected is ``1 - exp(t) w_fast / w_slow``. Ordinary block-to-block
        swings of the mean correlation while tracking are below ~0.05 on the benchmark
        runs; a kidnapped set drops by 0.15-0.3.
    z_rand_unconverged : float or None
        Floor (``SensorConfig.z_rand``'s role) used while the set has not converged (see
        :class:`localization.estimate.ClusterConfig`: one compact mode holding >= 90 % of
        the weight), e.g. after a global start. Several hypotheses then share the particles,
        each core holds few of them, and a low floor lets one block's noise decide between
        hypotheses; once converged the sensor's own (low) floor applies, so the reported
        covariance is the likelihood's, not the floor's. None: always the sensor's floor.
    min_ess_fraction : float
        Tempering floor: when a block's full likelihood would leave an effective sample size
        below this share of the particles, only the largest share of its log-likelihood
        that keeps it is applied (:func:`temper_to_ess`); 0 disables.
    inject_candidates : int
        Candidates drawn per injected particle; the injected ones are picked among them by
        the current block's likelihood.
    global_oversample : int
        A global initialization draws this many times ``n_particles``; the first
        resampling brings the count back to ``n_particles``.
    kld : bool
        KLD-adaptive particle count at each resampling.
    kld_epsilon, kld_delta : float
        KLD bound and confidence (Fox 2003).
    kld_bin_m, kld_bin_rad : float
        KLD histogram bin size.
    n_min, n_max : int
        KLD count limits.
    fit_threshold : float
        Echo model: a block is *explained* when the fit at the estimate (mean of the shares
        of measured peaks explained and of expected echoes heard, ``PoseEstimate.fit``) is
        at least this. Calibrated on tracked runs: the 1st percentile of the fit at the
        true pose (:func:`localization.calibration.calibrate_fit_threshold`) over the nine
        built-in runs at SNR 10 dB on their ideal maps is 0.63 (lowest 0.63, medians
        0.70-0.87); 0.6 leaves a little room for a built map's error.
    lost_after : int
        Echo model: this many unexplained blocks in a row make the status ``lost``; one
        makes it ``uncertain``.
    relocalize : bool
        Echo model: on an unexplained block, replace a share of the particles by poses that
        explain the block (:func:`localization.sensor.echo_proposals`, picked by
        likelihood): ``reseed_fraction`` on the first, twice that once lost, all of them
        after ``reseed_after`` unexplained blocks in a row (a global re-seed). An anchored
        filter (below) re-seeds near its estimate on the first unexplained block, and once
        lost replaces at most twice ``reseed_fraction`` by proposals from the whole map that
        carry the prior odds of a kidnap (``kidnap_prior_nats``).
    reseed_fraction : float
        Share replaced on the first unexplained block.
    reseed_after : int
        Unexplained blocks in a row before a full re-seed.
    proposal_candidates : int
        Proposals scored per particle replaced (and per particle of a global start's first
        block, of which half are proposals).
    anchor_gate_m, anchor_gate_deg : float
        While the filter is anchored (tracked start, never lost since), the proposals of a
        re-seed before it is lost stay within this distance and heading of the estimate: a
        block the estimate explains poorly does not open the door to a symmetric look-alike
        the motion so far rules out. Once lost, proposals come from the whole map.
    jump_dwell_blocks : int
        An estimate that contradicts dead reckoning - farther than the anchor gates and 4
        sigma (Mahalanobis) from where the odometry carried the last ``converged`` estimate,
        with the motion model's growing covariance - is reported ``uncertain`` until it has
        held for this many blocks (the last of them ``converged``; 0: never held back),
        counting only blocks the map can judge (``reckoned_evidence``'s rules below). Either the
        robot was carried there (a kidnap, rare) or the map is wrong where the odometry
        puts it (an incomplete map, common: measured on built maps, a robot leaving the
        mapped walls was lost, then re-localized onto a look-alike that explained the blocks
        as well as the truth would and reported ``converged`` metres off for up to 15
        blocks); the blocks cannot tell which, so a jump must hold before it is trusted.
        The estimate itself moves at once when the blocks prefer it by ``kidnap_prior_nats``
        (see ``report_reckoned``).
    report_reckoned : bool
        Echo model: while the particles' mode contradicts dead reckoning and the blocks do
        not prefer it over the best pose near the dead-reckoned one by ``kidnap_prior_nats``
        (evidence discounted by ``rival_memory``), report the dead-reckoned pose and its covariance
        (``PoseEstimate.reckoned``, status never ``converged``) instead of the look-alike.
    min_map_echoes : int
        A block counts as evidence for a jump only where the map predicts at least this
        many specular echoes at the dead-reckoned pose (0: everywhere). Where it predicts
        fewer, the map is silent (walls the mapping run never heard): a look-alike explaining
        the block better is no sign of a kidnap (measured on the fresh14d gallery's built
        map: the truth beyond the mapped walls' ends, no echo predicted there, a look-alike
        5.6 m away preferred by 8 nats a block).
    jump_heard_max : float
        Echo model, on a map built from runs (``SensorTables.complete`` false): a block
        counts as evidence for a jump only where fewer than this share of the echoes the
        map predicts at the dead-reckoned pose are heard (1: every block). Where they are
        heard, the map and the odometry agree; the peaks that pose leaves unexplained are
        walls the map lacks (a built map holds only what its run heard), and a look-alike
        elsewhere explaining them is no sign of a kidnap. On a complete map (a floor plan)
        an unexplained peak does contradict the pose, and every block counts: along a
        corridor, where the side walls are heard everywhere, only the end walls tell a kidnap.
        Measured over every trial of the localization benchmark: where the dead-reckoned
        pose was right (within 30 cm, built maps) the median block heard 0.9 of its
        predicted echoes; where the robot had been carried away, 0.13 (ideal maps) and 0.21
        (built maps).
    jump_missed_min : float
        Echo model, on a map built from runs, with ``jump_heard_max``: a block counts as
        evidence for a jump only where at least this many of the specular echoes the map
        predicts at the dead-reckoned pose go unheard (the count times the share not heard;
        0: no such test). One missing echo of two is what a wall the map lacks does to the
        echo behind it (measured on the kitchen's built map: the island, never heard by the
        mapping run, hides the wall behind it from a robot tracked along the west side; one
        of two predicted echoes heard, and a look-alike 4.7 m away taken as a kidnap); a
        robot carried away misses most of them. Over the far blocks of every trial of the
        localization benchmark (built maps, before this test) 1.5 kept 0.78 of the blocks
        where the robot had been carried away (``jump_heard_max`` alone 0.86) and 0.09 of
        those where the dead-reckoned pose was right (0.28).
    confirm_blocks : int
        A global start has no dead reckoning to hold a jump against: its first ``converged``
        estimate is reported ``uncertain`` until it has been ``converged`` on this many
        blocks that agree with each other through the odometry (each within the anchor
        gates or 4 sigma of the one before carried by the motion model; a block that
        contradicts its predecessor starts the count again; 0 or 1: at once). A look-alike
        that explains one or two blocks of a map wrong where the robot is (a built map
        missing walls) rarely keeps explaining them as the robot moves. A tracked start is
        confirmed by its prior. 8 (was 4): measured over every trial of the localization
        benchmark (46 runs, the benchmark's own trials and seeds), built maps, together with
        ``jump_missed_min``: blocks ``converged`` while metres off 189 -> 129 from this alone
        (``landing-neck`` 37 -> 18, ``alcove-straight`` 18 -> 0, ``l-room-straight``
        4 -> 0, ``workshop-line`` 6 -> 0), global successes 69 -> 67 of 138; ideal maps
        unchanged (6 converged while wrong, global 116 of 138, kidnaps 117 of 133). The
        price is about four more ``uncertain`` blocks at the start of a global start.
    confirm_fit : float
        Echo model: a block counts towards a global start's confirmation only when its fit at
        the estimate (``PoseEstimate.fit``) is at least this: the blocks must be explained
        as well as the truth explains a typical block, not merely above ``fit_threshold``
        (which says *not lost*). 0.7 is the lowest per-run median of the fit at the true
        pose over the nine built-in runs at SNR 10 dB on their ideal maps (medians
        0.70-0.87; see ``fit_threshold``). A look-alike on a built map missing walls where
        the robot is explains part of the echoes (first confirmed blocks of the benchmark's
        global starts that were metres off: median fit 0.70, against 0.82 for those at the
        truth on built maps and 0.86 on ideal maps).
    reconfirm_blocks : int
        Echo model: after a block the estimate does not explain (fit below
        ``fit_threshold``), a block is ``converged`` again only once this many blocks in a
        row would be (every other rule passed) with a fit of at least ``confirm_fit`` (0: at
        once, as before). A misfit says the map stopped explaining the blocks where the
        filter was; the first estimate that explains one above ``fit_threshold`` is often
        where the odometry carried the old pose, not where the robot is. Measured on the
        kitchen's built map: kidnapped 1.5-2.1 m, one to four blocks missed, then
        ``converged`` 2.1-2.5 m and 90 deg off at fits of 0.64-0.69.
    twin_margin_nats : float
        Echo model: a symmetric twin of the estimate (its image under a symmetry of the
        walls, :func:`localization.sensor.wall_symmetries`) is a *rival* while the evidence
        for the estimate over it (:func:`twin_evidence`) is below this. Known limit: on the
        built L-room map the fitted walls are a few cm asymmetric at the inside corner, the
        twin loses 1-2.5 nats per block, and a filter on the wrong twin stays ``converged``
        until the path turns (measured: 9-11 blocks per run). While a rival exists
        the status is not ``converged`` and rivals replace ``twin_fraction`` of the
        particles, so both modes are reported instead of a coin flip between them.
    twin_memory : float
        Forgetting factor of that evidence per block.
    twin_fraction : float
        Share of particles placed on the rivals at each block that has one.
    rival_proposals : int
        Echo model: poses drawn per block (:func:`~localization.sensor.echo_proposals`) to
        look for *rivals* - poses beyond ``rival_separation_m`` / ``rival_separation_deg``
        of the estimate that explain the block at least as well; 0 turns rivals off. Rivals
        move with the odometry, are refined on each block and carry their evidence like the
        twins; while the filter is anchored only a rival that explained the recent blocks
        better by ``rival_margin_nats`` counts, otherwise ties (``twin_margin_nats``) too.
        A counting rival keeps the status from ``converged`` and gets ``twin_fraction`` of
        the particles (:mod:`localization.particle_filter._rivals`).
        Measured: a robot carried 4.8 m along the long corridor (only the end wall's echo,
        now out of range, missing) was ``converged`` 4.8 m off for 10 blocks without them.
    max_rivals : int
        Rivals kept.
    rival_separation_m, rival_separation_deg : float
        How far from the estimate (and from each other) a rival is; closer ones merge.
    rival_drop_nats : float
        A rival the estimate beats by more than this (discounted evidence) is dropped.
    rival_margin_nats, rival_memory : float
        While anchored a rival counts when it explained the recent blocks better by more
        than ``rival_margin_nats`` (evidence discounted by ``rival_memory`` per block);
        otherwise when it is within ``twin_margin_nats`` of the estimate. A weak but lasting
        preference must add up: kidnapped from the T-hall's stem into its cross hall (the
        same 2.2 m width), only a head-on wall 4.5 m away, heard with probability ~0.4,
        tells the places apart (0.54 nats per block); with margin 3 and memory 0.8 the
        filter stayed ``converged`` 5 m off for 7 blocks, with 1.5 and 0.9 for 2.
    rival_refine_top : int
        Echo model: the best this many rival proposals (beyond the separation) are refined
        on the block before they are compared with the estimate (0: compared as drawn). A
        proposal is a few cm and degrees off the place it stands for; compared as drawn with
        the estimate (the filter's mode, on its peak) the truth was not held as a rival for
        two blocks after a kidnap from the T-hall's straight into its stem, though it
        explained them better by 2.6 nats each.
    rival_pair_share : float
        Echo model: share of the rival proposals that hear two of the block's peaks as two
        walls' echoes (:func:`~localization.sensor.pair_proposals`) rather than one: a
        single peak fixes a proposal only to a line along a wall, two fix the point. Found on
        the T-hall's ideal map: kidnapped from its straight into its stem, no one-peak
        proposal landed near the truth for two blocks (1 in 288 within 1 cm), which
        explained them better by 2.6 nats each; the status stayed ``converged`` 5 m off.
        Only an anchored filter's rivals use them (a tracked start followed without a
        jump, where a rival must be better to count): they find the ties too, which count
        against an unanchored estimate, and global starts on ideal maps fell from 154 to 141
        of 186 with them in every filter's rivals, to 146 as the global start's and
        re-seeds' proposals as well (harness).
    rival_doubt_nats : float
        While anchored, a rival that explained the recent blocks better by more than this
        (but not yet by ``rival_margin_nats``) keeps the status from ``converged`` without
        getting particles: the estimate is kept, the answer says another place explains the
        blocks better. Values above ``rival_margin_nats`` act as ``rival_margin_nats``.
        0.3 (0.5 until session 41): on a map built from runs, the first block after a
        kidnap from the T-hall's stem into its look-alike cross hall was heard better at
        four places along the cross hall by 0.42-0.43 nats each (two trials), so it was
        ``converged`` 5 m off. Cost on the tracked and kidnap trials of 92 runs (harness):
        2 % (ideal maps) and 4 % (built) fewer ``converged`` blocks, mostly in corridors
        whose ends are out of range; 0 costs 17 %, since ties hover about 0. Rivals taken
        together (``log sum exp``, 7-8 % fewer) were tried and dropped: in a corridor's
        middle four exact ties are together likelier than the estimate by log 4, and a
        robot tracked there lost ``converged`` (``test_rivals.py``'s corridor test).
    rival_admit_nats : float
        Echo model, unanchored filter (a global start): a proposal joins the rivals when it
        explains the block at least as well as the estimate less this (nats), not only when
        it explains it better. The truth after a global start on a built map is often a
        near tie block by block (measured on foundry-line: 0.1-0.2 nats either way for 13
        blocks, after 7 blocks where it was 5-6 nats better), so a strict test never held
        it and the look-alike was ``converged`` 2-3 m off.
    rival_pair_share_unanchored : float
        Echo model: ``rival_pair_share`` for an unanchored filter (two-peak proposals pin a
        pose where one-peak ones only fix a line along a wall; they find the ties a global
        start must know of).
    rival_tie_particles : bool
        Whether an unanchored filter's rivals that only tie (evidence gap in [0,
        ``twin_margin_nats``)) get particles. False: they keep the status from
        ``converged`` and nothing else; only rivals that explained the recent blocks better
        by more than ``rival_doubt_nats`` get particles (ties given particles made the
        reported pose swap between modes, and global starts on ideal maps fail: with the
        two-peak proposals 169 -> 149 of 204 starts, harness).
    open_map_global : {"uncertain", "confirm"}
        A global start on a map built from runs with an open wall end
        (:attr:`~localization.sensor.SensorTables.open_ends`): ``"uncertain"`` never
        reports it ``converged`` (the map has free space it knows nothing of, where the
        robot may hear walls like the mapped ones: parlour-mirror, the mapped half's mirror
        image, was ``converged`` 3-5 m off at the mirror). Status only: the filter confirms
        the start inside as on a closed map and then holds jumps against dead reckoning
        (with the confirmation itself withheld, the reported pose swapped between
        look-alikes and global starts on built maps fell from 87 to 75 of 204).
        ``"confirm"``: reported as on a closed map (a user who knows the robot is in the
        mapped part). A tracked start is not affected, unless it jumps (below).
    open_map_relocalized : bool
        A tracked filter whose estimate jumped beyond the anchor gates (it lost its track
        and found a place again, as after a kidnap) is in a global start's position:
        ``open_map_global`` applies to it from then on. Measured on the held-out cloister's
        built map (three open wall ends): a tracked run that left the mapped part was lost
        for 7 blocks, re-localized 4.5 m and 93 deg off and, after 34 blocks on that
        look-alike, reported it ``converged``.
    motion : MotionNoise
    cluster : ClusterConfig
    refine : RefineConfig
        Echo model: the Gaussian refinement of the converged mode (:mod:`localization.refine`),
        which reports ``pose`` and ``cov`` while it explains the blocks.
    """

    n_particles: int = 2000
    resample_ess_fraction: float = 0.5
    augmented: bool = True
    alpha_slow: float = 0.05
    alpha_fast: float = 0.5
    max_inject_fraction: float = 0.25
    inject_threshold_rho: float = 0.08
    min_ess_fraction: float = 0.05
    z_rand_unconverged: float | None = 0.01
    inject_candidates: int = 16
    global_oversample: int = 10
    kld: bool = False
    kld_epsilon: float = 0.05
    kld_delta: float = 0.01
    kld_bin_m: float = 0.2
    kld_bin_rad: float = math.radians(10.0)
    n_min: int = 200
    n_max: int = 20000
    fit_threshold: float = 0.6
    lost_after: int = 2
    relocalize: bool = True
    reseed_fraction: float = 0.25
    reseed_after: int = 4
    proposal_candidates: int = 4
    anchor_gate_m: float = 0.5
    anchor_gate_deg: float = 30.0
    kidnap_prior_nats: float = 5.0
    jump_dwell_blocks: int = 10
    report_reckoned: bool = True
    min_map_echoes: int = 2
    jump_heard_max: float = 0.5
    jump_missed_min: float = 1.5
    confirm_blocks: int = 8
    confirm_fit: float = 0.7
    reconfirm_blocks: int = 3
    twin_margin_nats: float = 3.0
    twin_memory: float = 0.8
    twin_fraction: float = 0.05
    rival_proposals: int = 96
    max_rivals: int = 4
    rival_separation_m: float = 0.5
    rival_separation_deg: float = 30.0
    rival_drop_nats: float = 10.0
    rival_margin_nats: float = 1.5
    rival_memory: float = 0.9
    rival_doubt_nats: float = 0.3
    rival_refine_top: int = 4
    rival_pair_share: float = 0.5
    rival_admit_nats: float = 1.0
    rival_pair_share_unanchored: float = 0.5
    rival_tie_particles: bool = False
    open_map_global: str = "uncertain"
    open_map_relocalized: bool = True
    motion: MotionNoise = field(default_factory=MotionNoise)
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)

    def __post_init__(self) -> None:
        if not 1 <= self.n_particles <= 10_000_000:
            raise ValueError(f"n_particles must be in [1, 1e7], got {self.n_particles}")
        if not 0 < self.resample_ess_fraction <= 1:
            raise ValueError(
                f"resample_ess_fraction must be in (0, 1], got {self.resample_ess_fraction}")
        if not (0 < self.alpha_slow < self.alpha_fast <= 1):
            raise ValueError("need 0 < alpha_slow < alpha_fast <= 1, got "
                             f"{self.alpha_slow}, {self.alpha_fast}")
        if not 0 <= self.max_inject_fraction <= 1:
            raise ValueError(
                f"max_inject_fraction must be in [0, 1], got {self.max_inject_fraction}")
        if not 1 <= self.global_oversample <= 100:
            raise ValueError(f"global_oversample must be in [1, 100], got {self.global_oversample}")
        if not 0 <= self.inject_threshold_rho <= 2:
            raise ValueError(
                f"inject_threshold_rho must be in [0, 2], got {self.inject_threshold_rho}")
        if self.z_rand_unconverged is not None and not 0 < self.z_rand_unconverged < 1:
            raise ValueError(
                f"z_rand_unconverged must be in (0, 1) or None, got {self.z_rand_unconverged}")
        if not 0 <= self.min_ess_fraction < 1:
            raise ValueError(f"min_ess_fraction must be in [0, 1), got {self.min_ess_fraction}")
        if self.inject_candidates < 1:
            raise ValueError(f"inject_candidates must be >= 1, got {self.inject_candidates}")
        if not 0 <= self.fit_threshold <= 1:
            raise ValueError(f"fit_threshold must be in [0, 1], got {self.fit_threshold}")
        if not 1 <= self.lost_after <= 100:
            raise ValueError(f"lost_after must be in [1, 100], got {self.lost_after}")
        if not 0 <= self.reseed_fraction <= 0.5:
            raise ValueError(f"reseed_fraction must be in [0, 0.5], got {self.reseed_fraction}")
        if not 1 <= self.reseed_after <= 1000:
            raise ValueError(f"reseed_after must be in [1, 1000], got {self.reseed_after}")
        if not 1 <= self.proposal_candidates <= 100:
            raise ValueError(
                f"proposal_candidates must be in [1, 100], got {self.proposal_candidates}")
        if not 0 < self.anchor_gate_m <= 100:
            raise ValueError(f"anchor_gate_m must be in (0, 100], got {self.anchor_gate_m}")
        if not 0 < self.anchor_gate_deg <= 180:
            raise ValueError(
                f"anchor_gate_deg must be in (0, 180], got {self.anchor_gate_deg}")
        if not 0 <= self.kidnap_prior_nats <= 100:
            raise ValueError(
                f"kidnap_prior_nats must be in [0, 100], got {self.kidnap_prior_nats}")
        if not (isinstance(self.jump_dwell_blocks, int)
                and 0 <= self.jump_dwell_blocks <= 1000):
            raise ValueError(
                f"jump_dwell_blocks must be an integer in [0, 1000], got {self.jump_dwell_blocks}")
        if not isinstance(self.report_reckoned, bool):
            raise ValueError(f"report_reckoned must be true or false, got {self.report_reckoned!r}")
        if not (isinstance(self.min_map_echoes, int) and 0 <= self.min_map_echoes <= 100):
            raise ValueError(
                f"min_map_echoes must be an integer in [0, 100], got {self.min_map_echoes}")
        if not 0 <= self.jump_heard_max <= 1:
            raise ValueError(f"jump_heard_max must be in [0, 1], got {self.jump_heard_max}")
        if not (math.isfinite(self.jump_missed_min) and self.jump_missed_min >= 0):
            raise ValueError("jump_missed_min must be finite and >= 0 (echoes), got "
                             f"{self.jump_missed_min}")
        if not 0 <= self.confirm_fit <= 1:
            raise ValueError(f"confirm_fit must be in [0, 1], got {self.confirm_fit}")
        if not (isinstance(self.reconfirm_blocks, int) and 0 <= self.reconfirm_blocks <= 1000):
            raise ValueError("reconfirm_blocks must be an integer in [0, 1000], got "
                             f"{self.reconfirm_blocks}")
        if not (isinstance(self.confirm_blocks, int) and 0 <= self.confirm_blocks <= 1000):
            raise ValueError(
                f"confirm_blocks must be an integer in [0, 1000], got {self.confirm_blocks}")
        if not 0 <= self.twin_margin_nats <= 1000:
            raise ValueError(
                f"twin_margin_nats must be in [0, 1000], got {self.twin_margin_nats}")
        if not 0 <= self.twin_memory < 1:
            raise ValueError(f"twin_memory must be in [0, 1), got {self.twin_memory}")
        if not 0 <= self.twin_fraction <= 0.5:
            raise ValueError(f"twin_fraction must be in [0, 0.5], got {self.twin_fraction}")
        if not 0 <= self.rival_proposals <= 100_000:
            raise ValueError(
                f"rival_proposals must be in [0, 100000], got {self.rival_proposals}")
        if not 1 <= self.max_rivals <= 100:
            raise ValueError(f"max_rivals must be in [1, 100], got {self.max_rivals}")
        if not 0 < self.rival_separation_m <= 100:
            raise ValueError(
                f"rival_separation_m must be in (0, 100], got {self.rival_separation_m}")
        if not 0 < self.rival_separation_deg <= 180:
            raise ValueError(
                f"rival_separation_deg must be in (0, 180], got {self.rival_separation_deg}")
        if not 0 < self.rival_drop_nats <= 1000:
            raise ValueError(
                f"rival_drop_nats must be in (0, 1000], got {self.rival_drop_nats}")
        if not 0 <= self.rival_margin_nats <= 1000:
            raise ValueError(
                f"rival_margin_nats must be in [0, 1000], got {self.rival_margin_nats}")
        if not (isinstance(self.rival_refine_top, int) and 0 <= self.rival_refine_top <= 100):
            raise ValueError(
                f"rival_refine_top must be an integer in [0, 100], got {self.rival_refine_top}")
        if not 0 <= self.rival_pair_share <= 1:
            raise ValueError(
                f"rival_pair_share must be in [0, 1], got {self.rival_pair_share}")
        if self.open_map_global not in ("uncertain", "confirm"):
            raise ValueError("open_map_global must be 'uncertain' or 'confirm', got "
                             f"{self.open_map_global!r}")
        if not 0 <= self.rival_pair_share_unanchored <= 1:
            raise ValueError("rival_pair_share_unanchored must be in [0, 1], got "
                             f"{self.rival_pair_share_unanchored}")
        if not 0 <= self.rival_admit_nats <= 1000:
            raise ValueError(
                f"rival_admit_nats must be in [0, 1000], got {self.rival_admit_nats}")
        if not 0 <= self.rival_doubt_nats <= 1000:
            raise ValueError(
                f"rival_doubt_nats must be in [0, 1000], got {self.rival_doubt_nats}")
        if not 0 <= self.rival_memory < 1:
            raise ValueError(f"rival_memory must be in [0, 1), got {self.rival_memory}")
        if not 1 <= self.n_min <= self.n_max:
            raise ValueError(f"need 1 <= n_min <= n_max, got {self.n_min}, {self.n_max}")

    @property
    def rival_params(self) -> RivalParams:
        """The ``rival_*`` fields as :class:`RivalParams`."""
        return RivalParams(proposals=self.rival_proposals, max_rivals=self.max_rivals,
                           separation_m=self.rival_separation_m,
                           separation_rad=math.radians(self.rival_separation_deg),
                           memory=self.rival_memory, drop_nats=self.rival_drop_nats,
                           refine_top=self.rival_refine_top,
                           pair_share=self.rival_pair_share)

    def to_json(self) -> str:
        """JSON of every field (nested dataclasses as objects)."""
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> FilterConfig:
        """Inverse of :meth:`to_json`."""
        d = json.loads(text)
        # checkpoints written before the threshold moved to correlation units
        d.pop("inject_threshold_nats", None)
        d["motion"] = MotionNoise(**d["motion"])
        d["cluster"] = ClusterConfig(**d["cluster"])
        # checkpoints written before the refinement existed get its defaults
        d["refine"] = RefineConfig(**d.get("refine", {}))
        return cls(**d)
