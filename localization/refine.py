"""Parametric refinement of the particle filter's converged mode (echo model).

The particle filter's likelihood is deliberately wide (range sigma 2 cm, a Doppler cosine
tolerance of the beam width) so that a global start and a kidnap find their basin, and its
set is spread by the motion model's floors. Its covariance is then the spread of that wide
posterior, not the precision of the estimate: on simulated runs the echo ranges at the true
pose scatter by 0.2 mm (robust scale) while the set reports 8-12 mm, so the normalized error
(NEES) was 0.05-0.8 instead of about 3.

Once the filter is ``converged`` this module follows the mode with a Gaussian: an iterated
extended Kalman filter on the same forward model (:func:`localization.sensor.predicted_echoes`):

* :func:`predict` carries the mean and covariance with the odometry (the motion model's
  Jacobians and its noise, :mod:`localization.motion`);
* :func:`update` matches the block's peaks to the predicted echoes one to one within a gate
  on the innovation, and runs Gauss-Newton on the prior plus the matched ranges and Doppler
  cosines (Jacobians by finite differences of the forward model, the same echo followed
  across the perturbed poses). Each range is weighted by the measured scatter plus the
  map's own range sigma of that echo (:func:`localization.sensor.map_range_sigma`), plus,
  for two echoes closer than the sonar's range resolution (one chip, 17 mm), the variance
  of their separation (:func:`unresolved_variance`): they make one peak between them.

The forward model is not exact either: it puts the robot on one straight line through the
block, and a block that turns is explained by a pose a little off the truth, by an error all
its echoes share. More echoes do not average that away, so it enters as a pose error of its
own (:func:`model_cov`, :func:`common_error_information`): the block measures the pose only to
within it.

The measurement noise is *measured*, not assumed: the post-fit residuals of recent blocks
are kept (:class:`Scatter`) and their robust scale (floored by ``range_floor_m`` /
``cos_floor``) is the noise of the next update. A first block starts from the sensor's own
sigmas, so the Gaussian begins as wide as the particle set and narrows as the residuals show
how well the model explains the data.

An update that does not explain its block says so (:class:`Refined` ``ok`` False, with the
reason): fewer than ``min_matches`` matched peaks, a normalized innovation (NIS per matched
measurement) above ``max_nis``, less than ``min_match_share`` of the block explained, or a
step of more than ``max_move_sigma`` from the prior. The filter then reports its particle
estimate for that block and keeps the Gaussian as predicted; the Gaussian restarts from the
particles when the two disagree by more than ``reset_mahalanobis`` or the status leaves
``converged`` (:class:`localization.particle_filter.ParticleFilter`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization import motion
from localization.motion import MotionNoise
from localization.sensor import Measurement, SensorTables, cos_sigma, predicted_echoes
from mapping.angles import wrap_angle

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: median of the chi-square distribution with one degree of freedom
_CHI2_1_MEDIAN = 0.454936


@dataclass(frozen=True)
class RefineConfig:
    """Settings of the refinement.

    Attributes
    ----------
    enabled : bool
        Follow the converged mode with the Gaussian (False: report the particle set's mode).
    range_floor_m : float
        Smallest range noise believed, whatever the residuals say (m). 0.2 mm (was 0.5):
        the post-fit residuals of the benchmark's straight blocks scatter by about 0.1 mm in
        range and 0.003-0.009 in cosine (on the map's 29-row bank), so floors of 0.5 mm /
        0.015 made every refined block's covariance several times its error (median NEES
        0.38 on straight blocks);
        the model's own error is now ``model_*`` / ``turn_*`` below, a pose error that more
        echoes do not average away.
    cos_floor : float
        Smallest Doppler-cosine noise believed (0.006, was 0.015). On the echo model's own
        58-row bank (:attr:`localization.sensor.SensorConfig.echo_bank_oversample`) the
        post-fit cosine residuals scatter by 0.0006-0.003 (on the map's 29 rows 0.003-0.009),
        so the floor now overstates the noise of most blocks; it stays because it also keeps
        a wrong match from being believed: 0.003 (with ``model_heading_rad`` 1 mrad) put
        stacks-line's refined blocks 2.5 and 5.9 cm off at a reported sd below 0.2 mm (its
        mean NEES 4.1 -> 2793; session 43).
    gate_sigma : float
        A peak matches a predicted echo only within this many innovation sigmas (per
        coordinate; range and cosine together as a 2-D distance).
    iterations : int
        Gauss-Newton iterations per block (each one forward-model call; a second changed
        the benchmark's tracking by < 0.1 mm: the ranges are linear over the prior's mm).
    step_m, step_rad : float
        Finite-difference steps of the Jacobians.
    min_matches : int
        Fewest matched peaks for an update: a pose has three unknowns, so four echoes leave
        one to check the others against. With three (a corridor's two side walls and one
        echo ahead) one biased echo went unnoticed: the T-hall stem's refined track sat
        7-12 mm off while reporting 1 mm (mean NEES 16); with four it falls back to the
        particles there (0.8). Rechecked on the 58-row bank (session 44, tracked runs on
        ideal maps): 3 lifts the runs whose blocks mostly hold 2-3 echoes into [1, 6]
        (lobby-line 0.43 -> 1.60, scullery-nook 0.45 -> 1.77, boathouse-open 0.48 -> 1.00)
        but t-hall-stem-east goes 0.35 -> 32 and parlour-mirror 0.84 -> 45; 2 puts
        stacks-line at 5363. The particles' wider covariance is the safe side.
    max_nis : float
        Largest mean normalized innovation squared per matched measurement (about 1 when the
        model explains the block) before the update is refused.
    min_match_share : float
        Smallest share of the block explained: the mean of the shares of measured peaks
        matched and of predicted echoes matched (as the filter's fit, on the matches that
        survive the fit). At the true pose of the benchmark's runs it was 0.14-1 (10th
        percentile 0.4-0.8: about 3 % of the blocks are refused); the echoes of a pose
        3-20 cm or 17 deg from a tight prior explained 0.19-0.4.
    max_move_sigma : float
        The update is refused when it moves the mean farther than this from the prior
        (Mahalanobis distance under the prior covariance): the matches then agree with
        another pose, not with the prior.
    scatter_memory : int
        Post-fit residuals kept (per kind) to measure the noise.
    reset_mahalanobis : float
        The Gaussian restarts from the particle set when the two means differ by more than
        this Mahalanobis distance (under the sum of their covariances).
    speed_scale : bool
        Estimate the block's odometry speed error with the pose (:func:`update`'s
        ``scale_sd``, from the motion model by :func:`speed_scale_sd`); False treats the
        odometry speed as exact.
    model_pos_m, model_heading_rad : float
        The forward model's own error as a pose error common to all of a block's echoes
        (:func:`model_cov`): position (m, per axis) and heading (rad) standard deviations on
        every block, however many echoes it holds (0: none). 0.05 mm and 3 mrad: a straight
        block's heading is off by a bias the echoes share (hexagon-straight: 0.4-0.9 deg
        off for blocks on end while the Gaussian reported 0.3).
    turn_pos_m_per_rad, turn_heading_per_rad : float
        The same for a turning block, added to those: the forward model puts the robot on
        one straight line through the block, so a block that turns by ``dtheta`` is
        explained by a pose off by about ``turn_pos_m_per_rad * |dtheta|`` (m, per axis) and
        ``turn_heading_per_rad * |dtheta|`` (rad). 2 mm and 0.05 rad per rad: over the
        benchmark's tracked runs on ideal maps (74 runs, session 37) the refined blocks
        turning 0.3-0.5 rad were off by 0.8 mm per axis and 0.8 deg (RMS) while the
        Gaussian reported 0.34 mm and 0.5 deg (mean NEES 15; straight blocks 0.9).
    """

    enabled: bool = True
    range_floor_m: float = 0.0002
    cos_floor: float = 0.006
    gate_sigma: float = 3.0
    iterations: int = 1
    step_m: float = 1e-4
    step_rad: float = 1e-4
    min_matches: int = 4
    max_nis: float = 9.0
    min_match_share: float = 0.45
    max_move_sigma: float = 4.0
    scatter_memory: int = 64
    reset_mahalanobis: float = 4.0
    speed_scale: bool = True
    model_pos_m: float = 0.00005
    model_heading_rad: float = 0.003
    turn_pos_m_per_rad: float = 0.002
    turn_heading_per_rad: float = 0.05

    def __post_init__(self) -> None:
        checks = (
            ("range_floor_m", "in (0, 0.1] m", 0 < self.range_floor_m <= 0.1),
            ("cos_floor", "in (0, 1]", 0 < self.cos_floor <= 1),
            ("gate_sigma", "in [1, 20]", 1 <= self.gate_sigma <= 20),
            ("iterations", "an integer in 1..20",
             isinstance(self.iterations, int) and 1 <= self.iterations <= 20),
            ("step_m", "in (0, 0.01] m", 0 < self.step_m <= 0.01),
            ("step_rad", "in (0, 0.01] rad", 0 < self.step_rad <= 0.01),
            ("min_matches", "an integer in 1..100",
             isinstance(self.min_matches, int) and 1 <= self.min_matches <= 100),
            ("max_nis", "in [1, 1000]", 1 <= self.max_nis <= 1000),
            ("min_match_share", "in [0, 1]", 0 <= self.min_match_share <= 1),
            ("max_move_sigma", "in (0, 100]", 0 < self.max_move_sigma <= 100),
            ("scatter_memory", "an integer in 8..10000",
             isinstance(self.scatter_memory, int) and 8 <= self.scatter_memory <= 10000),
            ("reset_mahalanobis", "in (0, 100]", 0 < self.reset_mahalanobis <= 100),
            ("model_pos_m", "in [0, 1] m", 0 <= self.model_pos_m <= 1),
            ("model_heading_rad", "in [0, 1] rad", 0 <= self.model_heading_rad <= 1),
            ("turn_pos_m_per_rad", "in [0, 1] m/rad", 0 <= self.turn_pos_m_per_rad <= 1),
            ("turn_heading_per_rad", "in [0, 1] rad/rad", 0 <= self.turn_heading_per_rad <= 1),
        )
        for name, allowed, ok in checks:
            if not ok:
                raise ValueError(f"RefineConfig.{name} must be {allowed}, "
                                 f"got {getattr(self, name)!r}")


@dataclass(frozen=True)
class Scatter:
    """Recent post-fit residuals: ``range_m`` (m) and ``cos`` (Doppler cosine), newest last."""

    range_m: FloatArray
    cos: FloatArray

    @staticmethod
    def none() -> Scatter:
        return Scatter(np.zeros(0), np.zeros(0))

    def add(self, range_m: FloatArray, cos: FloatArray, keep: int) -> Scatter:
        return Scatter(np.concatenate([self.range_m, range_m])[-keep:],
                       np.concatenate([self.cos, cos])[-keep:])


def robust_sigma(residuals: FloatArray, fallback: float, floor: float) -> float:
    """Robust scale of zero-mean residuals, ``sqrt(median(r^2) / 0.455)`` (the median of a
    chi-square with one degree of freedom), at least ``floor``; ``fallback`` for fewer than
    4 residuals."""
    r = np.asarray(residuals, dtype=np.float64)
    if r.size < 4:
        return float(max(fallback, floor))
    return float(max(math.sqrt(float(np.median(r * r)) / _CHI2_1_MEDIAN), floor))


def noise(tables: SensorTables, measurement: Measurement, scatter: Scatter,
          config: RefineConfig) -> tuple[float, float]:
    """Range and Doppler-cosine noise of the next update: the robust scale of the kept
    residuals, or the sensor's own sigmas while fewer than 4 are kept."""
    return (robust_sigma(scatter.range_m, tables.config.range_sigma_m, config.range_floor_m),
            robust_sigma(scatter.cos, cos_sigma(tables, measurement), config.cos_floor))


def model_cov(yaw_rate_rad_s: float, dt_s: float, config: RefineConfig) -> FloatArray:
    """Covariance (3, 3) of the pose error common to a block's echoes
    (:class:`RefineConfig`'s ``model_*`` and ``turn_*``): diagonal, the variances of the
    constant part plus those of a part growing linearly in the block's turn
    ``|dtheta| = |yaw_rate * dt|`` (standard deviation)."""
    d = abs(float(yaw_rate_rad_s) * float(dt_s))
    sp, sh = config.turn_pos_m_per_rad * d, config.turn_heading_per_rad * d
    vp = config.model_pos_m**2 + sp * sp
    return np.diag([vp, vp, config.model_heading_rad**2 + sh * sh])


def predict(mean: FloatArray, cov: FloatArray, speed_m_s: float, yaw_rate_rad_s: float,
            dt_s: float, noise_model: MotionNoise) -> tuple[FloatArray, FloatArray]:
    """EKF prediction with the odometry motion model: the mean by dead reckoning and the
    covariance ``F P F' + G S G'`` (``S`` the variances of rot1, trans, rot2 from
    :func:`localization.motion.motion_std`)."""
    rot1, trans, rot2 = motion.odometry_increment(speed_m_s, yaw_rate_rad_s, dt_s)
    s1, st, s2 = motion.motion_std(rot1, trans, rot2, noise_model)
    h1 = float(mean[2]) + rot1
    c, s = math.cos(h1), math.sin(h1)
    out = np.array([mean[0] + trans * c, mean[1] + trans * s,
                    float(wrap_angle(np.array(h1 + rot2)))])
    F = np.array([[1.0, 0.0, -trans * s], [0.0, 1.0, trans * c], [0.0, 0.0, 1.0]])
    G = np.array([[-trans * s, c, 0.0], [trans * c, s, 0.0], [1.0, 0.0, 1.0]])
    P = F @ cov @ F.T + G @ np.diag([s1 * s1, st * st, s2 * s2]) @ G.T
    return out, 0.5 * (P + P.T)


@dataclass(frozen=True)
class Refined:
    """One update's outcome.

    Attributes
    ----------
    ok : bool
        Whether the update explains the block (enough matches, NIS within ``max_nis``).
    mean, cov : ndarray (3,), (3, 3)
        Posterior (the prior when not ``ok``).
    matches : int
        Peaks matched to predicted echoes.
    nis : float
        Mean normalized innovation squared per matched measurement at the prior.
    range_residuals_m, cos_residuals : ndarray
        Post-fit residuals of the matched peaks (empty when not ``ok``).
    reason : str
        Why not ``ok`` ("" when ok).
    """

    ok: bool
    mean: FloatArray
    cov: FloatArray
    matches: int
    nis: float
    range_residuals_m: FloatArray
    cos_residuals: FloatArray
    reason: str = ""


def speed_scale_sd(speed_m_s: float, yaw_rate_rad_s: float, dt_s: float,
                   noise: MotionNoise) -> float:
    """Relative standard deviation of a block's odometry speed under the motion model: the
    translation's sigma over its length (:func:`localization.motion.motion_std`); 0 for a
    block that does not move.

    Measured on the benchmark's landing-line (ideal map, odometry speed noise 5 mm/s at
    0.125 m/s): the refined heading was off by 0.05-0.3 deg on the blocks whose odometry
    speed was within 1 % of the truth and by 0.6-1.3 deg on those 4-7.5 % off, while it
    reported 0.4-0.6 deg for all of them: the cosines' common scale error was not modelled.
    """
    rot1, trans, rot2 = motion.odometry_increment(speed_m_s, yaw_rate_rad_s, dt_s)
    if abs(trans) < 1e-9:
        return 0.0
    return float(motion.motion_std(rot1, trans, rot2, noise)[1] / abs(trans))


def resolution_m(tables: SensorTables) -> float:
    """Range resolution of the sonar: one chip of the m-sequence, ``c / (2 chip_rate)``
    (17 mm at 10 kHz); two echoes closer than this are one peak of the heat map."""
    sonar = tables.sonar
    return float(sonar.sound_speed_m_s / (2.0 * sonar.chip_rate_hz))


def unresolved_variance(range_m: FloatArray, cos: FloatArray, resolution: float
                        ) -> tuple[FloatArray, FloatArray]:
    """Extra range and Doppler-cosine variance of each predicted echo (k,) that another
    predicted echo lies within ``resolution`` of in range: the two make one heat-map peak
    somewhere between them, so the peak of either is off by up to their separation
    (variance ``(separation / 2)^2`` from the nearest such neighbour; 0 for a resolved echo).

    Measured on the held-out studio room: echoes 8.7 mm apart gave one peak 3.8 mm from the
    nearer, and the refinement, treating it as a 0.5 mm measurement, moved 12.5 mm with a
    reported sigma of 0.6 mm.
    """
    r = np.asarray(range_m, dtype=np.float64)
    c = np.asarray(cos, dtype=np.float64)
    k = r.size
    if k < 2:
        return np.zeros(k), np.zeros(k)
    d = np.abs(r[:, None] - r[None, :])
    np.fill_diagonal(d, np.inf)
    j = np.argmin(d, axis=1)
    near = d[np.arange(k), j] < resolution
    var_r = np.where(near, 0.25 * d[np.arange(k), j] ** 2, 0.0)
    dc = c - c[j]
    var_c = np.where(near & np.isfinite(dc), 0.25 * dc * dc, 0.0)
    return var_r, var_c


def _jacobians(tables: SensorTables, speed_m_s: float, x: FloatArray, config: RefineConfig
               ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, IntArray]:
    """Predicted echoes at ``x`` (range, cosine, map sigma, each (k,)), their Jacobians
    (k, 3) by forward differences and their wall sequences (k, order); an echo not found
    again at a perturbed pose (visibility changed) gets NaN rows."""
    h = np.array([config.step_m, config.step_m, config.step_rad])
    poses = np.repeat(x[None, :], 4, axis=0)
    poses[1:] += np.diag(h)
    b, sig = predicted_echoes(tables, speed_m_s, poses, parallel=False)
    k = int(b.count[0])
    r0, c0 = b.range_m[0, :k], b.cos_doppler[0, :k]
    s0 = np.zeros(k) if sig is None else np.asarray(sig[0, :k], dtype=np.float64)
    jr = np.full((k, 3), np.nan)
    jc = np.full((k, 3), np.nan)
    key0 = b.walls[0, :k]
    for p in range(1, 4):
        kp = int(b.count[p])
        same = np.all(b.walls[p, None, :kp, :] == key0[:, None, :], axis=2)     # (k, kp)
        dist = np.where(same, np.abs(b.range_m[p, None, :kp] - r0[:, None]), np.inf)
        j = np.argmin(dist, axis=1) if kp else np.zeros(k, dtype=np.int64)
        found = np.isfinite(dist[np.arange(k), j]) if kp else np.zeros(k, dtype=bool)
        jr[found, p - 1] = (b.range_m[p, j[found]] - r0[found]) / h[p - 1]
        jc[found, p - 1] = (b.cos_doppler[p, j[found]] - c0[found]) / h[p - 1]
    return r0, c0, s0, jr, jc, np.asarray(key0, dtype=np.int64)


def _match(dr: FloatArray, dc: FloatArray | None, var_r: FloatArray, var_c: FloatArray | None,
           gate: float) -> tuple[IntArray, IntArray]:
    """One-to-one matches (peak, echo) of normalized 2-D distance below ``gate`` (per
    coordinate sigma units), greedily from the closest; ``dr``/``dc`` are (peaks, echoes)
    innovations, ``var_*`` (peaks, echoes) their variances."""
    d2 = dr * dr / var_r
    if dc is not None and var_c is not None:
        d2 = d2 + dc * dc / var_c
    d2 = np.where(np.isfinite(d2), d2, np.inf)
    limit = gate * gate * (2.0 if dc is not None else 1.0)
    order = np.argsort(d2, axis=None)
    used_p: set[int] = set()
    used_e: set[int] = set()
    pk, ek = [], []
    for flat in order:
        if d2.flat[flat] > limit:
            break
        i, j = divmod(int(flat), d2.shape[1])
        if i in used_p or j in used_e:
            continue
        used_p.add(i)
        used_e.add(j)
        pk.append(i)
        ek.append(j)
    return np.array(pk, dtype=np.int64), np.array(ek, dtype=np.int64)


def update(tables: SensorTables, measurement: Measurement, mean: FloatArray, cov: FloatArray,
           sigma_r_m: float, sigma_c: float, config: RefineConfig,
           scale_sd: float = 0.0, common_cov: FloatArray | None = None) -> Refined:
    """Iterated EKF update of the Gaussian ``(mean, cov)`` with one block's peaks.

    ``sigma_r_m`` and ``sigma_c`` are the measurement noise (:func:`noise`); each matched
    range also carries its echo's map sigma. Matches are made at the prior (gated on the
    innovation covariance) and kept through the iterations.

    ``scale_sd`` is the relative error of the block's odometry speed
    (:func:`speed_scale_sd`). The heat map turns Doppler shifts into cosines with that speed,
    so every measured cosine of the block is the true one times ``v_true / v_odometry``: one
    error common to the block, not independent noise. It is estimated with the pose (a
    fourth unknown ``s``, measured cosine ``c (1 + s)``, prior ``N(0, scale_sd^2)``)
    and marginalized out of the returned covariance.

    ``common_cov`` (3, 3) is a pose error common to all the block's echoes (the forward
    model's own error, :func:`model_cov`): the block measures the pose only to within
    it, however many echoes it holds. The information ``M`` the matches carry is replaced
    by ``(M^-1 + Q)^-1 = (I + M Q)^-1 M`` (defined for a singular ``M`` too) and its
    gradient ``g`` by ``(I + M Q)^-1 g``.
    """
    x0 = np.asarray(mean, dtype=np.float64)
    P0 = np.asarray(cov, dtype=np.float64)
    peaks = measurement.peaks
    fail = Refined(False, x0, P0, 0, math.nan, np.zeros(0), np.zeros(0))
    if peaks is None or peaks.r.shape[0] == 0 or tables.walls.n == 0:
        return dataclasses.replace(fail, reason="no peaks")
    if (x0.shape != (3,) or P0.shape != (3, 3) or not np.all(np.isfinite(x0))
            or not np.all(np.isfinite(P0)) or np.linalg.eigvalsh(P0).min() <= 0):
        return dataclasses.replace(fail, reason="prior not a finite positive definite Gaussian")
    use_cos = bool(peaks.use_cos)
    r0, c0, s0, jr, jc, keys = _jacobians(tables, measurement.speed_m_s, x0, config)
    ok_e = np.all(np.isfinite(jr), axis=1) & (not use_cos or np.all(np.isfinite(jc), axis=1))
    if r0.size == 0 or not ok_e.any():
        return dataclasses.replace(fail, reason="no predicted echo")
    blend_r, blend_c = unresolved_variance(r0, c0, resolution_m(tables))
    var_r_e = np.einsum("ki,ij,kj->k", jr, P0, jr) + sigma_r_m**2 + s0**2 + blend_r
    dr = peaks.r[:, None] - r0[None, :]
    dc = var_c = None
    if use_cos:
        var_c_e = (np.einsum("ki,ij,kj->k", jc, P0, jc) + sigma_c**2 + blend_c
                   + (scale_sd * c0) ** 2)
        dc = peaks.c[:, None] - c0[None, :]
        var_c = np.broadcast_to(np.where(ok_e, var_c_e, np.inf), dc.shape)
    var_r = np.broadcast_to(np.where(ok_e, var_r_e, np.inf), dr.shape)
    pi, ei = _match(dr, dc, var_r, var_c, config.gate_sigma)
    n_meas = pi.size * (2 if use_cos else 1)
    if pi.size < config.min_matches:
        return dataclasses.replace(fail, matches=int(pi.size), reason="too few matches")
    nis = float(np.sum(dr[pi, ei] ** 2 / var_r[pi, ei]))
    if use_cos and dc is not None and var_c is not None:
        nis += float(np.sum(dc[pi, ei] ** 2 / var_c[pi, ei]))
    nis /= n_meas
    if nis > config.max_nis:
        return dataclasses.replace(fail, matches=int(pi.size), nis=nis,
                                   reason=f"innovation {nis:.1f} > {config.max_nis:g}")
    walls0 = keys[ei]
    z_r, z_c = peaks.r[pi], peaks.c[pi]
    R_r = sigma_r_m**2 + s0[ei] ** 2 + blend_r[ei]
    R_c = sigma_c**2 + blend_c[ei]
    info0 = np.linalg.inv(P0)
    # the speed scale s joins the pose as a fourth unknown (cosines only)
    scale = use_cos and scale_sd > 0
    info4 = np.zeros((4, 4))
    info4[:3, :3] = info0
    info4[3, 3] = 1.0 / scale_sd**2 if scale else 1.0
    s_hat = 0.0
    x = x_lin = x0.copy()
    rr, cc, J_r, J_c = r0[ei], c0[ei], jr[ei], jc[ei]
    W = 1.0 / R_r
    Wc = 1.0 / R_c
    keep = np.ones(pi.size, dtype=bool)
    A = info0
    model_q = None
    if common_cov is not None and np.any(np.asarray(common_cov) != 0):
        model_q = np.zeros((4, 4))
        model_q[:3, :3] = np.asarray(common_cov, dtype=np.float64)
    for it in range(config.iterations + 1):
        if 0 < it < config.iterations:
            at = _at(tables, measurement.speed_m_s, x, walls0, use_cos, config)
            if at is None:
                return dataclasses.replace(fail, matches=int(pi.size), nis=nis,
                                           reason="echo lost while refining")
            rr, cc, J_r, J_c = at
            x_lin = x.copy()
        if it == config.iterations:
            # one pass without the matches the fit leaves beyond the gate (a peak that is
            # another echo than the one it was paired with), from the last linearization
            moved = _delta(x, x_lin)
            bad = np.abs(z_r - rr - J_r @ moved) > config.gate_sigma * np.sqrt(R_r)
            if use_cos:
                bad |= (np.abs(z_c - cc * (1.0 + s_hat) - J_c @ moved)
                        > config.gate_sigma * np.sqrt(R_c))
            if not bad.any():
                break
            keep = ~bad
            if int(keep.sum()) < config.min_matches:
                return dataclasses.replace(fail, matches=int(keep.sum()), nis=nis,
                                           reason="too few matches fit")
        dx = _delta(x_lin, x0)
        w = np.where(keep, W, 0.0)
        J_r4 = np.column_stack([J_r, np.zeros(J_r.shape[0])])
        A = info4 + J_r4.T @ (J_r4 * w[:, None])
        g = J_r4.T @ (w * (z_r - rr + J_r @ dx))
        if use_cos:
            wc = np.where(keep, Wc, 0.0)
            J_c4 = np.column_stack([J_c, cc if scale else np.zeros(cc.shape[0])])
            A = A + J_c4.T @ (J_c4 * wc[:, None])
            g = g + J_c4.T @ (wc * (z_c - cc + J_c @ dx))
        if model_q is not None:
            M, g = common_error_information(A - info4, g, model_q)
            A = info4 + M
        step = np.linalg.solve(A, g)
        x = x0 + step[:3]                       # the prior mean plus the Gauss-Newton step
        s_hat = float(step[3])
        if not np.all(np.isfinite(x)):
            return dataclasses.replace(fail, matches=int(pi.size), nis=nis,
                                       reason="no finite step")
        x[2] = float(wrap_angle(np.array(x[2])))
    # post-fit residuals of the kept matches, linearized about the last evaluation
    moved = _delta(x, x_lin)
    post_r = (z_r - rr - J_r @ moved)[keep]
    post_c = (z_c - cc * (1.0 + s_hat) - J_c @ moved)[keep] if use_cos else np.zeros(0)
    used = int(keep.sum())
    share = 0.5 * (used / peaks.r.shape[0] + used / max(int(ok_e.sum()), used))
    if share < config.min_match_share:
        return dataclasses.replace(fail, matches=used, nis=nis,
                                   reason=f"explains {share:.2f} of the block "
                                   f"< {config.min_match_share:g}")
    move = _delta(x, x0)
    jump = math.sqrt(max(float(move @ info0 @ move), 0.0))
    if jump > config.max_move_sigma:
        return dataclasses.replace(fail, matches=used, nis=nis,
                                   reason=f"moved {jump:.1f} sigma from the prior "
                                   f"> {config.max_move_sigma:g}")
    P = np.linalg.inv(A)[:3, :3]                # the pose's marginal (s integrated out)
    return Refined(True, x, 0.5 * (P + P.T), used, nis, post_r, post_c)


def common_error_information(info: FloatArray, grad: FloatArray, q: FloatArray
                             ) -> tuple[FloatArray, FloatArray]:
    """Information and gradient of a measurement once an error common to it, of
    covariance ``q``, is added: ``info`` ``M`` (n, n) and ``grad`` ``g`` (n,) become
    ``(I + M q)^-1 M`` (``= (M^-1 + q)^-1`` for an invertible ``M``, defined for a
    singular one too: directions the measurement does not see stay unseen) and
    ``(I + M q)^-1 g``."""
    T = np.linalg.inv(np.eye(info.shape[0]) + info @ q)
    m = T @ info
    return 0.5 * (m + m.T), T @ grad


def _delta(x: FloatArray, x0: FloatArray) -> FloatArray:
    d = x - x0
    d[2] = float(wrap_angle(np.array(d[2])))
    return d


def _at(tables: SensorTables, speed_m_s: float, x: FloatArray, keys: IntArray,
        use_cos: bool, config: RefineConfig
        ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None:
    """Range, cosine and Jacobians at ``x`` of the echoes with wall sequences ``keys``
    (None when one of them is not predicted there)."""
    r0, c0, _, jr, jc, k0 = _jacobians(tables, speed_m_s, x, config)
    same = np.all(k0[None, :, :] == keys[:, None, :], axis=2)                 # (m, k)
    if not np.all(same.any(axis=1)):
        return None
    j = np.argmax(same, axis=1)
    if not np.all(np.isfinite(jr[j])) or (use_cos and not np.all(np.isfinite(jc[j]))):
        return None
    return r0[j], c0[j], jr[j], jc[j]


def mahalanobis(a: FloatArray, cov_a: FloatArray, b: FloatArray, cov_b: FloatArray) -> float:
    """Mahalanobis distance between two pose means under the sum of their covariances
    (heading difference wrapped)."""
    d = _delta(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    S = np.asarray(cov_a) + np.asarray(cov_b)
    try:
        return float(math.sqrt(max(float(d @ np.linalg.solve(S, d)), 0.0)))
    except np.linalg.LinAlgError:
        return math.inf
