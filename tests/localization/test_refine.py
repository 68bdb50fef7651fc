"""The Gaussian refinement of the converged mode (:mod:`localization.refine`).

Independent truths: the EKF prediction against a Monte Carlo of the odometry motion model it
linearizes; the update's mean and covariance against repeated exact echoes with known
Gaussian noise (the normalized error must average 3, the chi-square mean of three degrees
of freedom), also when the whole block is off by a common pose error of known covariance
(the model error of :func:`localization.refine.model_cov`); the common-error information
against the direct inverse ``(M^-1 + Q)^-1``; the Jacobian of a first-order echo against
the wall's normal. Edges: a clutter peak, a block no pose near the prior explains, a
stationary (range-only) block, no peaks, a bad prior; in the particle filter: refined only
while converged, exact checkpoints.
"""

from __future__ import annotations

import dataclasses
import io
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from localization import motion, refine
from localization.estimate import nees
from localization.motion import MotionNoise
from localization.particle_filter import FilterConfig, ParticleFilter
from localization.sensor import (
    Measurement,
    SensorConfig,
    SensorTables,
    build_tables,
    predicted_echoes,
    prepare_measurement,
)
from mapping.forward import WallSet, predicted_heatmap
from mapping.signal import SonarConfig
from mapping.wallmap import wallmap_from_walls
from tests.localization.helpers import ASYMMETRIC_ROOM, trajectory

FloatArray = NDArray[np.float64]
SONAR = SonarConfig()
ECHO = SensorConfig(model="echo")
WALLS = ASYMMETRIC_ROOM.reshape(-1, 4)
TRUTH = np.array([1.8, 1.2, 0.3])
SPEED = 0.15
CFG = refine.RefineConfig()


@pytest.fixture(scope="module")
def tables() -> SensorTables:
    return build_tables(wallmap_from_walls(WALLS), ECHO)


def _block(pose: FloatArray, speed_m_s: float = SPEED) -> Measurement:
    hm = predicted_heatmap(WallSet.from_array(WALLS), pose, speed_m_s, SONAR)
    return prepare_measurement(hm, ECHO)


def _exact(tables: SensorTables, pose: FloatArray, sigma_r: float, sigma_c: float,
           rng: np.random.Generator, speed_m_s: float = SPEED) -> Measurement:
    """A block whose peaks are the forward model's echoes at ``pose`` plus Gaussian noise
    (an unresolved echo also off by the extra variance the model gives it)."""
    meas = _block(pose, speed_m_s)
    b, _ = predicted_echoes(tables, speed_m_s, pose[None, :])
    k = int(b.count[0])
    r, c = b.range_m[0, :k], b.cos_doppler[0, :k]
    var_r, var_c = refine.unresolved_variance(r, c, refine.resolution_m(tables))
    assert meas.peaks is not None
    peaks = meas.peaks._replace(r=r + rng.normal(0.0, 1.0, k) * np.sqrt(sigma_r**2 + var_r),
                                c=c + rng.normal(0.0, 1.0, k) * np.sqrt(sigma_c**2 + var_c),
                                w=np.ones(k))
    return dataclasses.replace(meas, peaks=peaks)


# ---- prediction ----------------------------------------------------------------------------
@pytest.mark.parametrize(("v", "w"), [(0.15, 0.0), (0.2, 0.4), (-0.1, -0.2)])
def test_prediction_matches_a_monte_carlo_of_the_motion_model(v: float, w: float) -> None:
    noise = MotionNoise()
    mean0 = np.array([1.0, 2.0, 0.7])
    cov0 = np.diag([0.004**2, 0.003**2, 0.01**2])
    mean, cov = refine.predict(mean0, cov0, v, w, 1.023, noise)
    rng = np.random.default_rng(1)
    start = rng.multivariate_normal(mean0, cov0, size=200_000)
    moved = motion.predict(start, v, w, 1.023, noise, rng)
    np.testing.assert_allclose(mean, moved.mean(axis=0), atol=2e-4)
    np.testing.assert_allclose(cov, np.cov(moved.T), rtol=0.03, atol=1e-7)


def test_prediction_without_motion_keeps_the_gaussian() -> None:
    mean0, cov0 = np.array([1.0, 2.0, 0.7]), np.diag([1e-4, 2e-4, 3e-4])
    mean, cov = refine.predict(mean0, cov0, 0.0, 0.0, 1.023, MotionNoise())
    np.testing.assert_allclose(mean, mean0)
    np.testing.assert_allclose(cov, cov0)


# ---- update --------------------------------------------------------------------------------
def test_update_is_consistent_on_exact_echoes_with_known_noise(tables: SensorTables) -> None:
    """Prior drawn around the truth with its own covariance, peaks the exact echoes plus noise
    of the stated sigmas: the posterior error must be chi-square with 3 degrees of freedom
    in the posterior covariance (mean 3), and smaller than the prior's."""
    rng = np.random.default_rng(3)
    P0 = np.diag([0.01**2, 0.01**2, math.radians(1.0) ** 2])
    sr, sc = 0.001, 0.02
    values, prior_err, post_err = [], [], []
    for _ in range(150):
        prior = rng.multivariate_normal(TRUTH, P0)
        out = refine.update(tables, _exact(tables, TRUTH, sr, sc, rng), prior, P0, sr, sc, CFG)
        assert out.ok, out.reason
        values.append(nees(out.mean, out.cov, TRUTH))
        prior_err.append(math.hypot(*(prior[:2] - TRUTH[:2])))
        post_err.append(math.hypot(*(out.mean[:2] - TRUTH[:2])))
    assert 2.4 <= float(np.mean(values)) <= 3.7
    assert float(np.mean(post_err)) < 0.2 * float(np.mean(prior_err))


def test_a_common_speed_error_is_estimated_and_kept_in_the_covariance(
        tables: SensorTables) -> None:
    """The heat map turns Doppler into cosines with the odometry speed, so a speed off by a
    factor (1 + s) scales every cosine of the block by it. Blocks built that way (s drawn
    with sd 5 %, the exact echoes plus small independent noise): with ``scale_sd`` the
    posterior error is chi-square with 3 degrees of freedom again (mean 3); treating the
    speed as exact the covariance is overconfident (mean far above 3)."""
    rng = np.random.default_rng(5)
    P0 = np.diag([0.01**2, 0.01**2, math.radians(1.0) ** 2])
    sr, sc, s_sd = 0.001, 0.01, 0.05
    with_scale, without = [], []
    for _ in range(150):
        prior = rng.multivariate_normal(TRUTH, P0)
        meas = _exact(tables, TRUTH, sr, sc, rng)
        assert meas.peaks is not None
        s = rng.normal(0.0, s_sd)
        meas = dataclasses.replace(meas, peaks=meas.peaks._replace(c=meas.peaks.c * (1.0 + s)))
        a = refine.update(tables, meas, prior, P0, sr, sc, CFG, s_sd)
        b = refine.update(tables, meas, prior, P0, sr, sc, CFG, 0.0)
        if a.ok:
            with_scale.append(nees(a.mean, a.cov, TRUTH))
        if b.ok:
            without.append(nees(b.mean, b.cov, TRUTH))
    assert len(with_scale) >= 140
    assert 2.4 <= float(np.mean(with_scale)) <= 3.7
    assert float(np.mean(without)) > 6.0



def test_a_common_pose_error_is_kept_in_the_covariance(tables: SensorTables) -> None:
    """Blocks whose echoes are all those of a pose off the truth by one error drawn from
    ``Q`` (what a forward model wrong for the block does: a turn inside the block), plus
    small independent noise: with ``common_cov=Q`` the error of the estimate from the truth
    is chi-square with 3 degrees of freedom in the posterior covariance (mean 3); without it
    the covariance is overconfident (mean far above 3), and with a zero ``Q`` the update is
    the plain one exactly."""
    rng = np.random.default_rng(9)
    P0 = np.diag([0.01**2, 0.01**2, math.radians(1.0) ** 2])
    Q = np.diag([0.002**2, 0.002**2, math.radians(0.5) ** 2])
    sr, sc = 0.0002, 0.003
    with_q, without = [], []
    for _ in range(150):
        prior = rng.multivariate_normal(TRUTH, P0)
        meas = _exact(tables, rng.multivariate_normal(TRUTH, Q), sr, sc, rng)
        a = refine.update(tables, meas, prior, P0, sr, sc, CFG, 0.0, Q)
        b = refine.update(tables, meas, prior, P0, sr, sc, CFG, 0.0)
        if a.ok:
            with_q.append(nees(a.mean, a.cov, TRUTH))
        if b.ok:
            without.append(nees(b.mean, b.cov, TRUTH))
        zero = refine.update(tables, meas, prior, P0, sr, sc, CFG, 0.0, np.zeros((3, 3)))
        assert zero.ok == b.ok and np.array_equal(zero.mean, b.mean)
    assert len(with_q) >= 140
    assert 2.4 <= float(np.mean(with_q)) <= 3.7
    assert float(np.mean(without)) > 30.0


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(0, 3))
def test_common_error_information_is_the_inverse_of_the_summed_covariances(
        seed: int, rank: int) -> None:
    """``(I + M Q)^-1 M`` equals ``(M^-1 + Q)^-1`` for an invertible ``M`` (rank 4) and,
    for a singular one, the same on the directions the measurement sees,
    ``U (S^-1 + U' Q U)^-1 U'`` (``M = U S U'``, ``U`` its range): directions it does not
    see stay unseen. The gradient follows ``M``'s (``g = M d`` becomes ``m d``)."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(4, 4))
    M = a[:, :rank] @ a[:, :rank].T * 10.0 ** rng.uniform(0, 6)
    b = rng.normal(size=(4, 4))
    Q = b @ b.T * 10.0 ** rng.uniform(-6, 0)
    d = rng.normal(size=4)
    m, g = refine.common_error_information(M, M @ d, Q)
    np.testing.assert_allclose(m, m.T)
    vals, vecs = np.linalg.eigh(M)
    seen = vals > 1e-9 * max(1.0, float(vals.max()))
    U, S = vecs[:, seen], vals[seen]
    direct = U @ np.linalg.inv(np.diag(1.0 / S) + U.T @ Q @ U) @ U.T
    if rank == 4:
        np.testing.assert_allclose(direct, np.linalg.inv(np.linalg.inv(M) + Q), rtol=1e-6,
                                   atol=1e-9 * float(np.abs(direct).max()))
    scale = max(1.0, float(np.abs(direct).max()))
    np.testing.assert_allclose(m, direct, atol=1e-7 * scale)
    assert np.linalg.eigvalsh(m).min() >= -1e-7 * scale
    np.testing.assert_allclose(g, m @ d, atol=1e-7 * scale * max(1.0, float(np.abs(d).max())))
    np.testing.assert_allclose(m @ vecs[:, ~seen], 0.0, atol=1e-7 * scale)
    # a zero Q changes nothing
    m0, g0 = refine.common_error_information(M, M @ d, np.zeros((4, 4)))
    np.testing.assert_allclose(m0, M, rtol=1e-12, atol=1e-12)


def test_model_cov_is_the_constant_part_plus_a_part_linear_in_the_turn() -> None:
    cfg = refine.RefineConfig(model_pos_m=0.001, model_heading_rad=0.002,
                              turn_pos_m_per_rad=0.004, turn_heading_per_rad=0.05)
    straight = refine.model_cov(0.0, 1.023, cfg)
    np.testing.assert_allclose(straight, np.diag([1e-6, 1e-6, 4e-6]))
    turn = refine.model_cov(-0.3, 1.0, cfg)            # |dtheta| = 0.3 rad, either sign
    np.testing.assert_allclose(turn, np.diag([1e-6 + 0.0012**2, 1e-6 + 0.0012**2,
                                              4e-6 + 0.015**2]))
    np.testing.assert_array_equal(turn, refine.model_cov(0.3, 1.0, cfg))
    none = refine.RefineConfig(model_pos_m=0.0, model_heading_rad=0.0,
                               turn_pos_m_per_rad=0.0, turn_heading_per_rad=0.0)
    np.testing.assert_array_equal(refine.model_cov(0.5, 1.0, none), np.zeros((3, 3)))


def test_speed_scale_sd_is_the_motion_models_relative_translation_sigma() -> None:
    noise = MotionNoise()
    _, s_trans, _ = motion.motion_std(0.0, 0.15 * 1.023, 0.0, noise)
    assert refine.speed_scale_sd(0.15, 0.0, 1.023, noise) == pytest.approx(
        s_trans / (0.15 * 1.023))
    assert refine.speed_scale_sd(0.0, 0.0, 1.023, noise) == 0.0


def test_first_order_echo_jacobian_is_the_wall_normal(tables: SensorTables) -> None:
    """Range to a wall's specular point changes by -n . dp (n the wall's normal toward the
    robot): the south wall y = 0 gives d range / d y = +1, d range / d x = 0."""
    out = refine.update(tables, _exact(tables, TRUTH, 1e-4, 1e-3, np.random.default_rng(0)),
                        TRUTH + np.array([0.0, 0.004, 0.0]),
                        np.diag([1e-4, 1e-4, 1e-4]), 1e-4, 1e-3, CFG)
    assert out.ok
    # the 4 mm offset in y is taken out by the ranges (to within the 0.1 mm noise)
    assert abs(out.mean[1] - TRUTH[1]) < 3e-4 and abs(out.mean[0] - TRUTH[0]) < 3e-4


def test_a_clutter_peak_changes_nothing(tables: SensorTables) -> None:
    rng = np.random.default_rng(5)
    meas = _exact(tables, TRUTH, 0.001, 0.02, rng)
    assert meas.peaks is not None
    P0 = np.diag([0.005**2, 0.005**2, math.radians(1.0) ** 2])
    prior = TRUTH + np.array([0.003, -0.002, 0.01])
    clean = refine.update(tables, meas, prior, P0, 0.001, 0.02, CFG)
    p = meas.peaks
    cluttered = dataclasses.replace(meas, peaks=p._replace(
        r=np.append(p.r, 2.777), c=np.append(p.c, 0.123), w=np.append(p.w, 1.0)))
    out = refine.update(tables, cluttered, prior, P0, 0.001, 0.02, CFG)
    assert out.ok and out.matches == clean.matches
    np.testing.assert_allclose(out.mean, clean.mean, atol=1e-12)


def test_a_block_the_prior_does_not_explain_is_refused(tables: SensorTables) -> None:
    """The echoes of poses 3-20 cm or 17 deg away, against a 5 mm / 1 deg prior: no update,
    and it says why (too little of the block explained, or a step far beyond the prior)."""
    P0 = np.diag([0.005**2, 0.005**2, math.radians(1.0) ** 2])
    for shift, why in (([0.08, -0.05, 0.0], "explains"), ([0.2, 0.1, 0.0], "too few"),
                       ([0.0, 0.0, 0.3], "explains"), ([0.03, 0.03, 0.0], "explains")):
        meas = _exact(tables, TRUTH + np.array(shift), 0.001, 0.02, np.random.default_rng(6))
        out = refine.update(tables, meas, TRUTH, P0, 0.001, 0.02, CFG)
        assert not out.ok and out.reason.startswith(why), (shift, out.reason)
        np.testing.assert_array_equal(out.mean, TRUTH)
        np.testing.assert_array_equal(out.cov, P0)
    # a step beyond max_move_sigma of the prior: the matches agree with another pose
    meas = _exact(tables, TRUTH, 0.001, 0.02, np.random.default_rng(6))
    prior = TRUTH + np.array([0.006, 0.0, 0.0])
    assert refine.update(tables, meas, prior, P0, 0.001, 0.02, CFG).ok
    strict = dataclasses.replace(CFG, max_move_sigma=1.0)
    assert refine.update(tables, meas, prior, P0, 0.001, 0.02, strict).reason.startswith("moved")


def test_a_stationary_block_refines_position_and_leaves_heading_to_the_prior(
        tables: SensorTables) -> None:
    rng = np.random.default_rng(7)
    meas = _exact(tables, TRUTH, 0.001, 0.02, rng, speed_m_s=0.0)
    assert meas.peaks is not None and not meas.peaks.use_cos
    P0 = np.diag([0.01**2, 0.01**2, math.radians(5.0) ** 2])
    prior = TRUTH + np.array([0.006, -0.005, 0.05])
    out = refine.update(tables, meas, prior, P0, 0.001, 0.02, CFG)
    assert out.ok and out.cos_residuals.size == 0
    assert math.hypot(*(out.mean[:2] - TRUTH[:2])) < 0.002
    assert out.cov[2, 2] == pytest.approx(P0[2, 2], rel=1e-3)
    assert out.mean[2] == pytest.approx(prior[2], abs=1e-3)
    # with the model's common error (the filter passes it on every block): the ranges still
    # fix the position, to within that error, and the heading they do not see stays the prior's
    q = refine.model_cov(0.0, 1.023, CFG)
    held = refine.update(tables, meas, prior, P0, 0.001, 0.02, CFG, 0.0, q)
    assert held.ok and math.hypot(*(held.mean[:2] - TRUTH[:2])) < 0.002
    assert held.cov[0, 0] >= out.cov[0, 0] and held.cov[1, 1] >= out.cov[1, 1]
    assert held.cov[2, 2] == pytest.approx(P0[2, 2], rel=1e-3)
    assert held.mean[2] == pytest.approx(prior[2], abs=1e-3)


def test_no_peaks_or_a_bad_prior_is_refused(tables: SensorTables) -> None:
    meas = _block(TRUTH)
    assert meas.peaks is not None
    empty = dataclasses.replace(meas, peaks=meas.peaks._replace(
        r=np.zeros(0), c=np.zeros(0), w=np.zeros(0)))
    P0 = np.eye(3) * 1e-4
    assert refine.update(tables, empty, TRUTH, P0, 0.001, 0.02, CFG).reason == "no peaks"
    for mean, cov in ((np.array([np.nan, 1.0, 0.0]), P0), (TRUTH, np.zeros((3, 3)))):
        out = refine.update(tables, meas, mean, cov, 0.001, 0.02, CFG)
        assert not out.ok and "prior" in out.reason


def test_unresolved_echoes_get_the_variance_of_their_separation(tables: SensorTables) -> None:
    res = refine.resolution_m(tables)
    assert res == pytest.approx(340.0 / 20_000.0)
    var_r, var_c = refine.unresolved_variance(np.array([1.0, 1.008, 2.0, 3.0, 3.0 + 1.5 * res]),
                                              np.array([0.5, 0.7, 0.1, 0.2, 0.3]), res)
    np.testing.assert_allclose(var_r, [0.004**2, 0.004**2, 0.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(var_c, [0.01, 0.01, 0.0, 0.0, 0.0], atol=1e-15)
    assert [v.size for v in refine.unresolved_variance(np.array([1.0]), np.array([0.0]),
                                                       res)] == [1, 1]


# ---- the measured noise --------------------------------------------------------------------
def test_noise_is_the_robust_scale_of_kept_residuals_with_floors(tables: SensorTables) -> None:
    meas = _block(TRUTH)
    sr0, _ = refine.noise(tables, meas, refine.Scatter.none(), CFG)
    assert sr0 == tables.config.range_sigma_m            # nothing measured yet: the sensor's
    rng = np.random.default_rng(8)
    s = refine.Scatter.none().add(rng.normal(0, 0.002, 5000), rng.normal(0, 0.05, 5000), 5000)
    sr, sc = refine.noise(tables, meas, s, CFG)
    assert sr == pytest.approx(0.002, rel=0.05) and sc == pytest.approx(0.05, rel=0.05)
    # one wild residual in twenty does not move a robust scale much
    wild = s.add(np.full(250, 0.5), np.full(250, 1.0), 5250)
    assert refine.noise(tables, meas, wild, CFG)[0] < 0.0025
    tiny = refine.Scatter.none().add(np.full(10, 1e-6), np.full(10, 1e-6), 64)
    assert refine.noise(tables, meas, tiny, CFG) == (CFG.range_floor_m, CFG.cos_floor)
    assert s.add(np.ones(3), np.ones(3), 8).range_m.shape == (8,)


@pytest.mark.parametrize(("field", "value"), [
    ("range_floor_m", 0.0), ("cos_floor", -1.0), ("gate_sigma", 0.5), ("iterations", 0),
    ("min_matches", 0), ("max_nis", 0.5), ("scatter_memory", 4), ("reset_mahalanobis", 0.0),
    ("min_match_share", 1.5), ("max_move_sigma", 0.0), ("model_pos_m", -0.001),
    ("model_heading_rad", 2.0), ("turn_pos_m_per_rad", -1.0), ("turn_heading_per_rad", 1.5),
])
def test_settings_are_validated(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        refine.RefineConfig(**{field: value})  # type: ignore[arg-type]


def test_mahalanobis_wraps_the_heading() -> None:
    cov = np.diag([1e-4, 1e-4, 1e-4])
    a, b = np.array([0.0, 0.0, math.pi - 0.005]), np.array([0.0, 0.0, -math.pi + 0.005])
    assert refine.mahalanobis(a, cov, b, cov) == pytest.approx(0.01 / math.sqrt(2e-4))


# ---- in the particle filter ----------------------------------------------------------------
ODO = [(SPEED, 0.0)] * 5 + [(SPEED, 0.25)] * 5
START = np.array([0.8, 0.9, 0.2])
DT = 1.023


def _run(tables: SensorTables, config: FilterConfig, seed: int = 0
         ) -> tuple[ParticleFilter, list, FloatArray]:  # type: ignore[type-arg]
    truth = trajectory(START, ODO, DT)
    hms = [predicted_heatmap(WallSet.from_array(WALLS), p, SPEED, SONAR) for p in truth]
    pf = ParticleFilter(tables, config, np.random.default_rng(seed), pose=START,
                        cov=np.diag([0.03**2, 0.03**2, math.radians(3.0) ** 2]))
    ests = []
    for k, hm in enumerate(hms):
        v, w = ODO[k - 1] if k else (SPEED, 0.0)
        ests.append(pf.step(hm, v, w, DT if k else 0.0))
    return pf, ests, truth


def test_filter_reports_the_refined_mode_only_while_converged(tables: SensorTables) -> None:
    cfg = FilterConfig(n_particles=500)
    _, ests, truth = _run(tables, cfg)
    _, plain, _ = _run(tables, dataclasses.replace(cfg, refine=dataclasses.replace(
        cfg.refine, enabled=False)))
    assert all(e.refined == (e.status == "converged") or not e.refined for e in ests)
    refined = [k for k, e in enumerate(ests) if e.refined]
    assert len(refined) >= 6 and not any(e.refined for e in plain)
    err = [math.hypot(*(ests[k].pose[:2] - truth[k, :2])) for k in refined]
    err_plain = [math.hypot(*(plain[k].pose[:2] - truth[k, :2])) for k in refined]
    assert float(np.mean(err)) < float(np.mean(err_plain))
    # the modes stay the particles' view
    assert all(np.array_equal(ests[k].modes[0].mean, ests[k].modes[0].mean) for k in refined)


def test_checkpoint_keeps_the_refined_track(tables: SensorTables) -> None:
    pf, ests, truth = _run(tables, FilterConfig(n_particles=300))
    assert ests[-1].refined and pf.track is not None
    buf = io.BytesIO()
    np.savez(buf, **pf.state_dict())  # type: ignore[arg-type]
    buf.seek(0)
    with np.load(buf, allow_pickle=False) as npz:
        clone = ParticleFilter.from_state_dict({k: npz[k] for k in npz.files}, tables)
    assert clone.track is not None
    np.testing.assert_array_equal(clone.track[0], pf.track[0])
    np.testing.assert_array_equal(clone.scatter.range_m, pf.scatter.range_m)
    hm = predicted_heatmap(WallSet.from_array(WALLS),
                           motion.predict_mean(truth[-1], SPEED, 0.25, DT), SPEED, SONAR)
    a, b = pf.step(hm, SPEED, 0.25, DT), clone.step(hm, SPEED, 0.25, DT)
    np.testing.assert_array_equal(a.pose, b.pose)
    np.testing.assert_array_equal(a.cov, b.cov)
    old = {k: v for k, v in pf.state_dict().items() if not k.startswith(("track", "scatter"))}
    assert ParticleFilter.from_state_dict(old, tables).track is None


def test_noise_block_and_kidnap_drop_the_refined_track(tables: SensorTables) -> None:
    """At the edges the filter reports the particles, not a Gaussian that cannot explain the
    block: a block of pure noise (no peak: `uncertain`) and the blocks after a kidnap (the
    echoes of a pose 1.5 m away)."""
    from mapping.heatmap import doppler_heatmap

    pf, ests, truth = _run(tables, FilterConfig(n_particles=500))
    assert ests[-1].refined and pf.track is not None
    noise = doppler_heatmap(np.random.default_rng(1).standard_normal(SONAR.block_samples),
                            SPEED, SONAR)
    est = pf.step(noise, SPEED, 0.0, DT)
    assert est.status != "converged" and not est.refined and pf.track is None
    # back on the echoes, then carried 1.5 m away: never a refined estimate far from the truth
    pf, ests, truth = _run(tables, FilterConfig(n_particles=500), seed=1)
    away = np.array([3.2, 0.8, math.pi / 2])
    for k in range(4):
        pose = motion.predict_mean(away, SPEED, 0.0, k * DT)
        est = pf.step(predicted_heatmap(WallSet.from_array(WALLS), pose, SPEED, SONAR),
                      SPEED, 0.0, DT)
        if k == 0:
            assert est.status != "converged" and not est.refined and pf.track is None
        if est.refined:
            assert math.hypot(*(est.pose[:2] - pose[:2])) < 0.3
