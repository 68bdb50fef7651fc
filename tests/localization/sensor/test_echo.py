"""Tests of the echo sensor model: kernel vs its twin, geometry truth, the left/right fold, the
range-only (stationary) case, noise blocks, data-driven proposals and the echo settings.

Blocks are the forward model's heat maps (:func:`mapping.forward.predicted_heatmap`) of known
walls, scored on the ideal map of the same walls (:func:`mapping.wallmap.wallmap_from_walls`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from localization.sensor import (
    ECHO_NATS,
    Measurement,
    SensorConfig,
    SensorTables,
    build_tables,
    cos_sigma,
    echo_proposals,
    end_weights,
    explanation,
    heatmap_run,
    map_range_sigma,
    pair_proposals,
    prepare_measurement,
    score_poses,
    soft_end_walls,
    uniform_free_poses,
)
from localization.sensor._kernels import (  # only to compare the kernels with their twins
    _EchoPeaks,
    _EchoTerms,
    end_weight_rows,
    map_sigma_rows,
    score_echo,
)
from mapping.forward import ForwardParams, WallSet, echoes, echoes_batch, predicted_heatmap
from mapping.heatmap import doppler_heatmap, heatmap_of_run
from mapping.path import PAPER_SPEED_M_S
from mapping.signal import SonarConfig
from mapping.synthetic import Wall as SyntheticWall
from mapping.synthetic import run_truth, synthetic_run
from mapping.wallmap import WallMap, wallmap_from_walls
from tests.localization.helpers import ASYMMETRIC_ROOM
from tests.localization.sensor.naive import end_weights_numpy, map_sigma_numpy, naive_echo

FloatArray = NDArray[np.float64]
ECHO = SensorConfig(model="echo")
SONAR = SonarConfig()
#: kappa below which the kernel skips a (peak, echo) pair: exp(-18)
KAPPA_CUT = math.exp(-18.0)

ASYM = ASYMMETRIC_ROOM.reshape(-1, 4)
#: Three walls, no two parallel, open on the west: every echo is a wall or one inside corner.
OPEN_THREE = np.array([[0.0, 0.0, 4.2, 0.3], [4.2, 0.3, 3.6, 3.2], [3.6, 3.2, 0.4, 2.8]])
#: A corridor 2 m wide closed at x = 8: mirror symmetric about its centre line y = 1.
CORRIDOR = np.array([[-1.0, 0.0, 8.0, 0.0], [-1.0, 2.0, 8.0, 2.0], [8.0, 0.0, 8.0, 2.0]])
#: The same corridor with a 0.4 m stub on the north wall only: no mirror symmetry.
CORRIDOR_STUB = np.vstack([CORRIDOR, [[4.0, 2.0, 4.0, 1.6]]])


def _tables(walls: FloatArray, **map_kwargs: Any) -> SensorTables:
    return build_tables(wallmap_from_walls(walls, **map_kwargs), ECHO)


def _block(walls: FloatArray, pose: FloatArray, speed_m_s: float) -> Measurement:
    """The echo measurement of the forward model's heat map of ``walls`` at ``pose``."""
    hm = predicted_heatmap(WallSet.from_array(walls), np.asarray(pose, dtype=np.float64),
                           speed_m_s, SONAR)
    return prepare_measurement(hm, ECHO)


@pytest.fixture(scope="module")
def asym() -> SensorTables:
    return _tables(ASYM)


@pytest.fixture(scope="module")
def open_three() -> SensorTables:
    return _tables(OPEN_THREE)


# ---- the kernel against its twin -----------------------------------------------------------
def _tolerance(peaks: _EchoPeaks, terms: _EchoTerms, n_pred: int) -> float:
    """Largest |ll| difference the kernel's cut-off (kappa < exp(-18) read as 0) can make."""
    per_peak = (1.0 - terms.eps) * KAPPA_CUT / terms.eps
    per_echo = terms.p_max * KAPPA_CUT / (1.0 - terms.p_max)
    return 1e-9 + float(np.sum(peaks.w)) * per_peak + n_pred * per_echo


def _random_case(seed: int, n_meas: int, kmax: int, use_cos: bool, n: int = 6
                 ) -> tuple[NDArray[np.int64], FloatArray, FloatArray, FloatArray, _EchoPeaks,
                            _EchoTerms]:
    """Random poses' echoes (NaN padded past ``count``), half of them near a measured peak,
    some outside the range window, some with negative amplitude."""
    rng = np.random.default_rng(seed)
    meas_r = rng.uniform(0.1, 5.5, n_meas)
    meas_c = rng.uniform(-1.0, 1.0, n_meas)
    w = np.where(rng.random(n_meas) < 0.2, 0.0, rng.uniform(0.0, 2.0, n_meas))
    sig_r, sig_c = float(rng.uniform(0.005, 0.1)), float(rng.uniform(0.01, 1.0))
    la = np.minimum(rng.normal(-1.0, 1.0, n_meas), 0.0)
    peaks = _EchoPeaks(r=meas_r, c=meas_c, w=w, la=la, sig_r=sig_r, sig_c=sig_c,
                       use_cos=use_cos)
    lo = float(rng.uniform(0.0, 0.5))
    terms = _EchoTerms(eps=float(rng.uniform(0.01, 0.5)), p_max=float(rng.uniform(0.0, 0.95)),
                       rel_lo=lo, rel_hi=float(rng.uniform(lo + 0.01, 1.0)), r_min=0.15,
                       r_max=5.0, sig_a=float(rng.choice([0.0, rng.uniform(0.1, 2.0)])))
    count = rng.integers(0, kmax + 1, size=n)
    pr = rng.uniform(0.0, 6.0, (n, kmax))
    pc = rng.uniform(-1.0, 1.0, (n, kmax))
    if n_meas:
        near = rng.random((n, kmax)) < 0.5
        j = rng.integers(0, n_meas, size=(n, kmax))
        pr = np.where(near, meas_r[j] + rng.normal(0.0, 2 * sig_r, (n, kmax)), pr)
        pc = np.where(near, meas_c[j] + rng.normal(0.0, 2 * sig_c, (n, kmax)), pc)
    pa = rng.uniform(-0.6, 1.0, (n, kmax))
    pad = np.arange(kmax)[None, :] >= count[:, None]
    pr, pc, pa = (np.where(pad, np.nan, x) for x in (pr, pc, pa))
    return count, pr, pc, pa, peaks, terms


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_meas=st.integers(0, 7), kmax=st.integers(0, 7),
       use_cos=st.booleans(), with_map_sigma=st.booleans(), with_amplitude=st.booleans())
def test_echo_kernel_matches_naive_twin(seed: int, n_meas: int, kmax: int, use_cos: bool,
                                        with_map_sigma: bool, with_amplitude: bool) -> None:
    count, pr, pc, pa, peaks, terms = _random_case(seed, n_meas, kmax, use_cos)
    ms = (np.random.default_rng(seed + 1).uniform(0.0, 0.05, pr.shape) if with_map_sigma
          else None)
    amp = (np.where(np.isnan(pa), np.nan, np.random.default_rng(seed + 2).uniform(
        -0.2, 1.0, pr.shape)) if with_amplitude else None)
    got = score_echo(count, pr, pc, pa, peaks, terms, ms, amp)
    want = naive_echo(count, pr, pc, pa, peaks, terms, ms, amp)
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got[:, 0], want[:, 0], rtol=0,
                               atol=_tolerance(peaks, terms, kmax))
    np.testing.assert_allclose(got[:, 1:], want[:, 1:], rtol=0, atol=1e-9 + KAPPA_CUT)
    assert np.all((got[:, 1:] >= 0.0) & (got[:, 1:] <= 1.0 + 1e-12))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 300), n_meas=st.integers(0, 7),
       kmax=st.integers(0, 7), use_cos=st.booleans())
def test_echo_kernel_parallel_twin_gives_the_same_numbers(seed: int, n: int, n_meas: int,
                                                          kmax: int, use_cos: bool) -> None:
    """The parallel echo kernel (chunks of poses over numba's threads) against the serial
    one: every pose's arithmetic is the same, so the numbers are equal bit for bit, over
    chunk boundaries and for an empty set."""
    count, pr, pc, pa, peaks, terms = _random_case(seed, n_meas, kmax, use_cos, n)
    ms = np.random.default_rng(seed + 1).uniform(0.0, 0.05, pr.shape)
    serial = score_echo(count, pr, pc, pa, peaks, terms, ms, parallel=False)
    np.testing.assert_array_equal(score_echo(count, pr, pc, pa, peaks, terms, ms,
                                             parallel=True), serial)


def test_echo_kernel_edge_cases() -> None:
    """No measured peak: everything is explained (1), the expected echoes are all missed.
    No predicted echo: every peak is clutter, nothing was expected (heard 1). Both: 0, 1, 1."""
    terms = _EchoTerms(eps=0.05, p_max=0.9, rel_lo=0.1, rel_hi=0.4, r_min=0.15, r_max=5.0)
    none = _EchoPeaks(r=np.zeros(0), c=np.zeros(0), w=np.zeros(0), la=np.zeros(0), sig_r=0.02,
                      sig_c=0.05, use_cos=True)
    two = _EchoPeaks(r=np.array([1.0, 2.0]), c=np.array([0.5, -0.5]), w=np.array([1.0, 2.0]),
                     la=np.zeros(2), sig_r=0.02, sig_c=0.05, use_cos=True)
    # pose 0: echoes at full and quarter level (detection 0.9 and 0.45), and one outside the
    # range window (ignored, though the strongest); pose 1: no echo
    count = np.array([3, 0])
    pr = np.array([[1.0, 3.0, 7.0], [np.nan] * 3])
    pc = np.array([[0.5, 0.0, 0.0], [np.nan] * 3])
    pa = np.array([[0.8, 0.2, 9.0], [np.nan] * 3])
    got = score_echo(count, pr, pc, pa, none, terms)
    np.testing.assert_allclose(got[0], [math.log(1 - 0.9) + math.log(1 - 0.45), 1.0, 0.0],
                               atol=1e-12)
    np.testing.assert_allclose(got[1], [0.0, 1.0, 1.0], atol=1e-12)
    got = score_echo(count, pr, pc, pa, two, terms)
    # pose 0: the 1 m peak is explained exactly, the 2 m one is clutter; the 3 m echo missed
    np.testing.assert_allclose(got[0], [2 * math.log(0.05) + math.log(1 - 0.45), 1 / 3,
                                        0.9 / (0.9 + 0.45)], atol=1e-12)
    np.testing.assert_allclose(got[1], [3 * math.log(0.05), 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(got, naive_echo(count, pr, pc, pa, two, terms), atol=1e-12)


def test_explanation_matches_twin_on_forward_model_echoes(asym: SensorTables) -> None:
    """Wiring: ``explanation`` scores the forward model's echoes of the map's walls (order and
    range from the config), with the block's Doppler-cosine width, as the twin does."""
    pose = np.array([1.3, 1.1, 0.4])
    m = _block(ASYM, pose, 0.2)
    rng = np.random.default_rng(4)
    poses = np.vstack([pose, uniform_free_poses(asym, 200, rng)])
    ex = explanation(asym, m, poses)
    cfg = asym.config
    params = ForwardParams(max_order=cfg.echo_order,
                           max_range_m=cfg.max_range_m + 3 * cfg.range_sigma_m)
    b = echoes_batch(asym.walls, poses, m.speed_m_s, SONAR, params)
    assert m.peaks is not None and np.isnan(b.range_m).any()      # padding is exercised
    peaks = m.peaks._replace(sig_c=cos_sigma(asym, m))
    terms = _EchoTerms(eps=cfg.clutter, p_max=cfg.p_detect, rel_lo=cfg.detect_lo,
                       rel_hi=cfg.detect_hi, r_min=cfg.min_range_m, r_max=cfg.max_range_m,
                       sig_a=cfg.amplitude_sigma)
    assert terms.sig_a > 0 and m.peaks.la.size >= 2       # levels are compared
    want = naive_echo(b.count, b.range_m, b.cos_doppler, b.amplitude, peaks, terms)
    np.testing.assert_allclose(ex.log_likelihood, want[:, 0],
                               atol=_tolerance(peaks, terms, b.range_m.shape[1]))
    np.testing.assert_allclose(ex.explained, want[:, 1], atol=1e-7)
    np.testing.assert_allclose(ex.heard, want[:, 2], atol=1e-7)
    assert ex.n_peaks == m.n_peaks > 0
    # the score is the log-likelihood in correlation units, NaN off the active area
    off = np.array([[50.0, 50.0, 0.0]])
    rho = score_poses(asym, m, np.vstack([poses[:3], off]))
    np.testing.assert_allclose(rho[:3], 1.0 + ex.log_likelihood[:3] / ECHO_NATS, atol=1e-12)
    assert np.isnan(rho[3])


def test_explanation_refuses_a_measurement_of_another_model(asym: SensorTables) -> None:
    hm = predicted_heatmap(WallSet.from_array(ASYM), [1.3, 1.1, 0.4], 0.2, SONAR)
    m = prepare_measurement(hm, SensorConfig())
    with pytest.raises(ValueError, match="echo"):
        explanation(asym, m, np.zeros((1, 3)))


# ---- geometry truth ------------------------------------------------------------------------
def _neighbours(pose: FloatArray) -> FloatArray:
    """``pose`` displaced by 10 cm in 8 directions and rotated by +-10 deg."""
    a = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    moved = pose + np.column_stack([0.1 * np.cos(a), 0.1 * np.sin(a), np.zeros(8)])
    turned = pose + np.array([[0.0, 0.0, math.radians(10)], [0.0, 0.0, -math.radians(10)]])
    return np.vstack([moved, turned])


@pytest.mark.parametrize("speed", [PAPER_SPEED_M_S, 0.2, -0.15])
@pytest.mark.parametrize(("scene", "pose"), [
    ("asym", (1.3, 1.1, 0.4)), ("asym", (2.44, 0.99, -2.75)), ("asym", (0.8, 1.88, 0.88)),
    ("open_three", (2.0, 1.4, 2.2)), ("open_three", (2.9, 1.0, -0.7)),
])
def test_true_pose_beats_poses_10cm_or_10deg_off(
        scene: str, pose: tuple[float, float, float], speed: float,
        request: pytest.FixtureRequest) -> None:
    tables: SensorTables = request.getfixturevalue(scene)
    walls = ASYM if scene == "asym" else OPEN_THREE
    truth = np.array(pose)
    m = _block(walls, truth, speed)
    ex = explanation(tables, m, np.vstack([truth, _neighbours(truth)]))
    ll = ex.log_likelihood
    assert m.n_peaks >= 3
    assert np.all(ll[0] > ll[1:] + 3.0), ll[0] - ll[1:]     # >= 3 nats: a clear preference


def test_ideal_block_is_explained_at_the_true_pose(open_three: SensorTables) -> None:
    """At the paper's speed the true pose explains >= 90 % of the peaks and hears >= 90 %
    of the expected echoes, at 20 random poses of a scene without parallel walls (measured:
    >= 0.996 both)."""
    rng = np.random.default_rng(7)
    poses = uniform_free_poses(open_three, 400, rng)
    poses = poses[(poses[:, 0] > 0.6) & (poses[:, 0] < 3.4) & (poses[:, 1] > 0.6)
                  & (poses[:, 1] < 2.6)][:20]
    assert poses.shape[0] == 20
    for pose in poses:
        m = _block(OPEN_THREE, pose, PAPER_SPEED_M_S)
        ex = explanation(open_three, m, pose[None])
        assert m.n_peaks >= 2
        assert ex.explained[0] >= 0.9 and ex.heard[0] >= 0.9, (pose, ex)


# ---- folded left / right -------------------------------------------------------------------
def _mirror(pose: FloatArray) -> FloatArray:
    """``pose`` reflected about the corridor's centre line y = 1."""
    return np.array([pose[0], 2.0 - pose[1], -pose[2]])


@pytest.fixture(scope="module")
def corridors() -> dict[bool, SensorTables]:
    """The tables of the symmetric (True) and the stub (False) corridor."""
    return {True: _tables(CORRIDOR), False: _tables(CORRIDOR_STUB)}


@pytest.mark.parametrize("pose", [(2.0, 1.0, 0.3), (3.0, 0.7, 0.4), (1.5, 1.3, -0.2)])
def test_mirror_pose_scores_alike_only_in_a_mirror_symmetric_scene(
        pose: tuple[float, float, float], corridors: dict[bool, SensorTables]) -> None:
    """Eq. 1 only knows cos(theta): in a corridor symmetric about y = 1 the reflected pose
    hears the same ranges and Doppler cosines and scores the same; a stub on one wall
    breaks the tie."""
    truth = np.array(pose)
    for walls, symmetric in ((CORRIDOR, True), (CORRIDOR_STUB, False)):
        tables = corridors[symmetric]
        m = _block(walls, truth, 0.2)
        ex = explanation(tables, m, np.stack([truth, _mirror(truth), truth + [0, 0.1, 0]]))
        ll = ex.log_likelihood
        assert ll[0] > ll[2] + 3.0                        # the pose is still pinned down
        if symmetric:
            assert abs(ll[0] - ll[1]) < 1e-9
            assert abs(ex.explained[0] - ex.explained[1]) < 1e-9
        else:
            assert ll[0] > ll[1] + 3.0


#: The corridor with an absorbing north wall (R = 0.4): geometrically still mirror symmetric.
ABSORBING_NORTH = np.array([1.0, 0.4, 1.0])


@pytest.mark.parametrize("pose", [(2.0, 0.7, 0.3), (3.0, 0.6, 0.4), (1.5, 0.8, -0.2),
                                  (5.0, 1.4, 0.1)])
def test_levels_tell_an_absorbing_wall_from_its_mirror(pose: tuple[float, float, float]) -> None:
    """Ranges and Doppler cosines cannot tell a pose from its mirror in a corridor whose walls
    are symmetric but one of which absorbs (R = 0.4): the levels can. Comparing each peak's
    level with its echoes' (after the block's common gain) puts the truth >= 3 nats above
    the mirror, where without levels the two lie within 1.6 nats (and either way round)."""
    truth = np.array(pose)
    hm = predicted_heatmap(WallSet.from_array(CORRIDOR, ABSORBING_NORTH), truth, 0.2, SONAR)
    gaps = {}
    for sigma in (0.0, SensorConfig().amplitude_sigma):
        cfg = SensorConfig(model="echo", amplitude_sigma=sigma)
        tables = build_tables(wallmap_from_walls(CORRIDOR, ABSORBING_NORTH), cfg)
        ll = explanation(tables, prepare_measurement(hm, cfg),
                         np.stack([truth, _mirror(truth)])).log_likelihood
        gaps[sigma] = float(ll[0] - ll[1])
    assert abs(gaps[0.0]) < 1.6
    assert gaps[SensorConfig().amplitude_sigma] > 3.0


# ---- a robot standing still ----------------------------------------------------------------
def test_stationary_block_is_range_only_and_heading_free(asym: SensorTables) -> None:
    pose = np.array([1.3, 1.1, 0.4])
    hm = predicted_heatmap(WallSet.from_array(ASYM), pose, 0.0, SONAR)
    assert not hm.direction_observable
    m = prepare_measurement(hm, ECHO)
    assert m.peaks is not None and not m.peaks.use_cos and not m.direction_observable
    headings = np.linspace(-np.pi, np.pi, 13)
    for xy in ((1.3, 1.1), (2.2, 0.7)):
        poses = np.column_stack([np.full(13, xy[0]), np.full(13, xy[1]), headings])
        ll = explanation(asym, m, poses).log_likelihood
        assert np.ptp(ll) <= 1e-9
        assert np.ptp(score_poses(asym, m, poses)) <= 1e-9


def test_stationary_block_reads_each_echo_once(asym: SensorTables) -> None:
    pose = np.array([1.3, 1.1, 0.4])
    m = _block(ASYM, pose, 0.0)
    assert m.peaks is not None
    assert np.unique(np.round(m.peaks.r, 3)).size == m.n_peaks
    assert explanation(asym, m, pose[None]).heard[0] >= 0.5


# ---- blocks without echoes -----------------------------------------------------------------
def test_noise_blocks_give_no_evidence(asym: SensorTables) -> None:
    """White noise through eq. 1 gives no peak at all (3 seeds): every pose then 'explains'
    the block (nothing to explain, share 1 by definition) and hears none of its echoes
    (share 0). |Gaussian| noise as a heat map gives at most a stray peak, which random poses
    almost never explain."""
    rng = np.random.default_rng(2)
    poses = uniform_free_poses(asym, 300, rng)
    for seed in range(3):
        x = np.random.default_rng(seed).standard_normal(SONAR.block_samples)
        hm = doppler_heatmap(x, 0.2, SONAR)
        m = prepare_measurement(hm, ECHO)
        assert m.n_peaks == 0
        ex = explanation(asym, m, poses)
        assert ex.n_peaks == 0 and np.all(ex.explained == 1.0) and np.all(ex.heard == 0.0)
        H = np.abs(np.random.default_rng(seed).standard_normal(hm.H.shape))
        flat = prepare_measurement(dataclasses.replace(hm, H=H), ECHO)
        assert flat.n_peaks <= 2
        if flat.n_peaks:
            assert float(np.mean(explanation(asym, flat, poses).explained)) < 0.1


# ---- proposals -----------------------------------------------------------------------------
def test_proposals_lie_on_free_cells(asym: SensorTables) -> None:
    m = _block(ASYM, np.array([1.3, 1.1, 0.4]), 0.2)
    for seed in range(3):
        p = echo_proposals(asym, m, 1500, np.random.default_rng(seed))
        assert p.shape == (1500, 3) and np.all(asym.free_at(p[:, :2]))
        assert np.all(np.abs(p[:, 2]) <= np.pi)


WALL = np.array([[0.0, 0.0, 4.0, 0.0]])


@pytest.fixture(scope="module")
def one_wall() -> SensorTables:
    return _tables(WALL, margin_m=1.5)


@pytest.mark.parametrize("speed", [0.2, -0.2])
def test_proposals_hear_the_peak_as_the_wall_echo(one_wall: SensorTables, speed: float) -> None:
    """One wall, one peak at range r and Doppler cosine c: the proposals stand r from the wall
    line, over the segment, at a heading from which that wall's echo has cosine c."""
    m = _block(WALL, np.array([1.5, 0.8, 0.5]), speed)
    assert m.peaks is not None and m.n_peaks == 1 and m.peaks.use_cos
    r, c = float(m.peaks.r[0]), float(m.peaks.c[0])
    p = echo_proposals(one_wall, m, 1000, np.random.default_rng(0))
    at_r = (np.abs(np.abs(p[:, 1]) - r) <= 0.01) & (p[:, 0] >= 0.0) & (p[:, 0] <= 4.0)
    assert at_r.mean() >= 0.8
    walls = WallSet.from_array(WALL)
    for pose in p[at_r][:60]:
        e = echoes(walls, pose, speed, SONAR)
        assert e.k == 1 and abs(e.range_m[0] - r) < 0.01 and abs(e.cos_doppler[0] - c) < 1e-3
    assert np.mean(explanation(one_wall, m, p[at_r]).explained) > 0.95


@pytest.mark.parametrize("pose", [(1.3, 1.1, 0.4), (2.6, 0.9, -2.0)])
def test_pair_proposals_hear_two_peaks_and_land_on_the_pose(asym: SensorTables,
                                                            pose: tuple[float, ...]) -> None:
    """Two peaks and two walls fix a point: in the asymmetric room (no symmetry to land on
    instead; 11-12 peaks, 6 walls), 1 % or more of the two-peak proposals lie within 2 cm /
    2 deg of the true pose (measured 1.3-7 % over three poses and seeds), against at most
    0.5 % of as many one-peak proposals (measured 0-0.25 %: they fix the robot only to a
    line along a wall), on the free space."""
    truth = np.array(pose)
    m = _block(ASYM, truth, 0.2)
    assert m.peaks is not None and m.n_peaks >= 2
    rng = np.random.default_rng(0)
    pairs = pair_proposals(asym, m, 400, rng)
    assert 100 <= pairs.shape[0] <= 400 and np.all(asym.free_at(pairs[:, :2]))

    def near(p: FloatArray) -> float:
        d = np.hypot(p[:, 0] - truth[0], p[:, 1] - truth[1])
        h = np.abs(np.angle(np.exp(1j * (p[:, 2] - truth[2]))))
        return float(np.mean((d < 0.02) & (h < math.radians(2.0))))

    single = near(echo_proposals(asym, m, pairs.shape[0], rng, pair_share=0.0))
    assert near(pairs) >= 0.01 and single <= 0.005 and near(pairs) >= 4 * single
    # fewer than two peaks, or a range-only block's headings: no pair, or uniform
    one = dataclasses.replace(m, peaks=m.peaks._replace(r=m.peaks.r[:1], c=m.peaks.c[:1],
                                                        w=m.peaks.w[:1], la=m.peaks.la[:1]))
    assert pair_proposals(asym, one, 50, rng).shape == (0, 3)
    mixed = echo_proposals(asym, m, 300, rng, pair_share=0.5)
    assert mixed.shape == (300, 3) and np.all(asym.free_at(mixed[:, :2]))


def test_range_only_proposals_spread_their_headings(one_wall: SensorTables) -> None:
    m = _block(WALL, np.array([1.5, 0.8, 0.5]), 0.0)
    assert m.peaks is not None and not m.peaks.use_cos
    p = echo_proposals(one_wall, m, 2000, np.random.default_rng(1))
    at_r = np.abs(np.abs(p[:, 1]) - m.peaks.r[0]) <= 0.01
    assert at_r.mean() >= 0.8
    h = p[at_r, 2]
    assert abs(np.mean(np.exp(1j * h))) < 0.1
    counts, _ = np.histogram(h, bins=8, range=(-np.pi, np.pi))
    assert counts.min() >= 0.08 * h.size


def test_proposals_without_peaks_are_uniform_free_poses(asym: SensorTables) -> None:
    x = np.random.default_rng(0).standard_normal(SONAR.block_samples)
    m = prepare_measurement(doppler_heatmap(x, 0.2, SONAR), ECHO)
    assert m.n_peaks == 0
    got = echo_proposals(asym, m, 50, np.random.default_rng(3))
    np.testing.assert_array_equal(got, uniform_free_poses(asym, 50, np.random.default_rng(3)))


# ---- tables and settings -------------------------------------------------------------------
def test_free_at_and_covered_read_the_nearest_cell() -> None:
    wm = wallmap_from_walls(OPEN_THREE)
    coverage = np.zeros(wm.shape, dtype=bool)
    coverage[:, : wm.shape[1] // 2] = True                  # the west half only
    tables = build_tables(dataclasses.replace(wm, coverage=coverage), ECHO)
    x_mid = wm.x_m[wm.shape[1] // 2]
    pts = np.array([[x_mid - 0.5, 1.5], [x_mid + 0.5, 1.5], [-20.0, 1.5]])
    assert tables.covered(pts).tolist() == [True, False, False]
    assert tables.free_at(pts).tolist() == [True, True, False]
    on_wall = np.array([[2.0, 0.0 + 2.0 * 0.3 / 4.2]])       # on the south wall
    assert not tables.free_at(on_wall)[0] and tables.covered(np.array([[1.0, 1.5]]))[0]


@pytest.mark.parametrize(("field", "value"), [
    ("echo_order", 0), ("echo_order", 5),
    ("range_sigma_m", 0.0), ("range_sigma_m", 1.5), ("range_sigma_m", math.nan),
    ("cos_sigma_min", 0.0), ("cos_sigma_min", 2.5),
    ("cos_sigma_beam", -0.1), ("cos_sigma_beam", 11.0),
    ("clutter", 0.0), ("clutter", 1.0),
    ("p_detect", -0.1), ("p_detect", 1.0),
    ("detect_lo", -0.1), ("detect_lo", 0.4),
    ("detect_hi", 1.5),
    ("max_peaks", 0), ("max_peaks", 201),
    ("peak_snr", -1.0), ("peak_snr", 1001.0),
    ("amplitude_sigma", -0.1), ("amplitude_sigma", 10.5), ("amplitude_sigma", math.nan),
    ("echo_bank_oversample", 0), ("echo_bank_oversample", 9), ("echo_bank_oversample", 1.5),
])
def test_echo_settings_are_validated(field: str, value: float) -> None:
    bad: dict[str, Any] = {field: value}
    with pytest.raises(ValueError, match=f"^{field} must be"):
        SensorConfig(model="echo", **bad)


def test_echo_model_needs_a_map_with_walls() -> None:
    raster_only = WallMap(G=np.zeros((40, 40)), origin_m=(0.0, 0.0), resolution_m=0.05)
    with pytest.raises(ValueError, match="walls"):
        build_tables(raster_only, ECHO)
    build_tables(raster_only, SensorConfig())             # the G models do not need them


# ---- the map's own uncertainty -------------------------------------------------------------
def test_map_range_sigma_adds_offset_and_angle_in_quadrature() -> None:
    """One wall along y = 0 from x = 0 to 4 (middle x = 2), offset sigma 1 cm, angle sigma
    5 mrad: a bounce 1.5 m from the middle is uncertain by sqrt(0.01^2 + (1.5 * 0.005)^2)."""
    wm = wallmap_from_walls(np.array([[0.0, 0.0, 4.0, 0.0]]))
    wm = dataclasses.replace(wm, wall_sigma=np.array([[0.01, 0.005, 0.0]]))
    tables = build_tables(wm, SensorConfig(model="echo"))
    b = echoes_batch(tables.walls, np.array([[3.5, 1.0, 0.0], [2.0, 1.0, 0.0]]), 0.1, SONAR,
                     ForwardParams(max_order=1))
    sig = map_range_sigma(tables, b)
    assert sig is not None
    assert sig[0, 0] == pytest.approx(math.hypot(0.01, 1.5 * 0.005))
    assert sig[1, 0] == pytest.approx(0.01)
    ideal = build_tables(wallmap_from_walls(np.array([[0.0, 0.0, 4.0, 0.0]])),
                         SensorConfig(model="echo"))
    assert map_range_sigma(ideal, b) is None


def test_tables_know_whether_the_map_claims_every_wall() -> None:
    """A map made from geometry (a floor plan) is complete; one whose provenance lists the
    runs it was built from holds only the walls they heard."""
    wm = wallmap_from_walls(np.array([[0.0, 0.0, 4.0, 0.0]]))
    assert build_tables(wm, SensorConfig(model="echo")).complete
    built = dataclasses.replace(wm, provenance={"runs": [{"path": "a.npz", "sha256": "0"}]})
    assert not build_tables(built, SensorConfig(model="echo")).complete


def test_soft_ends_run_free_ends_on_and_weigh_bounces_by_the_end_sigma() -> None:
    """An L of two walls joined at (0, 0) with free ends at (4, 0) and (0, 3), endpoint
    sigma 10 cm: only the free ends move (by 2.5 sigma), and a bounce exactly at a free end
    counts one half, 2 sigma inside 0.977, 1 sigma outside 0.159."""
    walls = WallSet.from_array(np.array([[0.0, 0.0, 4.0, 0.0], [0.0, 3.0, 0.0, 0.0]]))
    run_on, sig = soft_end_walls(walls, np.array([[0.0, 0.0, 0.1], [0.0, 0.0, 0.1]]))
    np.testing.assert_allclose(sig, [[0.0, 0.1], [0.1, 0.0]])
    np.testing.assert_allclose(run_on.segments_m, [[[0.0, 0.0], [4.25, 0.0]],
                                                   [[0.0, 3.25], [0.0, 0.0]]])
    idx = np.array([[0, -1], [0, -1], [0, -1], [1, 0]])
    pts = np.array([[[4.0, 0.0], [np.nan, np.nan]], [[3.8, 0.0], [np.nan, np.nan]],
                    [[4.1, 0.0], [np.nan, np.nan]], [[0.0, 2.9], [2.0, 0.0]]])
    w = end_weights(walls, sig, idx, pts)
    np.testing.assert_allclose(w, [0.5, 0.97725, 0.15866, 0.84134], atol=1e-4)


def test_an_open_end_runs_on_by_its_own_sigma_and_stops_at_the_next_wall() -> None:
    """Per-end sigmas (``WallMap.wall_end_sigma``): a wall along y = 0 whose east end (4, 0)
    the runs never looked past (sigma 1 m) runs on 2.5 m, to (6.5, 0), its observed west end
    (sigma 2 cm) by 5 cm; a wall along x = 0 whose open north end (0, 1) points at a
    crossing wall at y = 2 stops there (1 m of run-on, not 2.5). A NaN end falls back to
    the wall's endpoint sigma. The weights of a bounce 1 m beyond the open end: Phi(-1)."""
    walls = WallSet.from_array(np.array([[-1.0, 0.0, 4.0, 0.0], [0.0, -0.5, 0.0, 1.0],
                                         [-2.0, 2.0, 2.0, 2.0]]))
    wsig = np.array([[0.0, 0.0, 0.03], [0.0, 0.0, 0.03], [0.0, 0.0, 0.03]])
    es = np.array([[0.02, 1.0], [np.nan, 1.0], [0.0, 0.0]])
    run_on, sig = soft_end_walls(walls, wsig, end_sigma=es)
    np.testing.assert_allclose(sig, [[0.02, 1.0], [0.03, 1.0], [0.0, 0.0]])
    np.testing.assert_allclose(run_on.segments_m, [[[-1.05, 0.0], [6.5, 0.0]],
                                                   [[0.0, -0.575], [0.0, 2.0]],
                                                   [[-2.0, 2.0], [2.0, 2.0]]])
    w = end_weights(walls, sig, np.array([[0, -1]]),
                    np.array([[[5.0, 0.0], [np.nan, np.nan]]]))
    np.testing.assert_allclose(w, [0.15866], atol=1e-4)
    # without per-end sigmas, the wall's own endpoint sigma at both ends, as before
    same, _ = soft_end_walls(walls, wsig)
    np.testing.assert_allclose(same.segments_m[0], [[-1.075, 0.0], [4.075, 0.0]])


def test_tables_read_the_wall_end_sigmas_of_a_built_map() -> None:
    """``build_tables`` takes ``WallMap.wall_end_sigma`` (the fit's record in provenance);
    a map that does not record it (geometry, older maps) gives None."""
    wm = wallmap_from_walls(np.array([[0.0, 0.0, 4.0, 0.0], [0.0, 0.0, 0.0, 3.0]]))
    assert build_tables(wm, SensorConfig(model="echo")).end_sigma is None
    built = dataclasses.replace(wm, provenance={"runs": [{"path": "a.npz", "sha256": "0"}],
                                                "fit": {"end_sigma_m": [[0.0, 1.0],
                                                                        [0.0, 0.05]]}})
    es = build_tables(built, SensorConfig(model="echo")).end_sigma
    assert es is not None
    np.testing.assert_allclose(es, np.array([[0.0, 1.0], [0.0, 0.05]]))
    bad = dataclasses.replace(built, provenance={"fit": {"end_sigma_m": [[0.0, -1.0]]}})
    assert np.isnan(bad.wall_end_sigma).all()


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 40), st.integers(1, 7), st.integers(1, 3),
       st.integers(0, 2**32 - 1))
def test_map_uncertainty_kernels_match_their_numpy_twins(n_walls: int, n: int, k: int,
                                                         order: int, seed: int) -> None:
    """End weights and map range sigma: numba kernels against the numpy code they replaced,
    on random walls, sigmas (some 0), bounce lists padded with -1 / NaN, points on and off
    the walls."""
    rng = np.random.default_rng(seed)
    seg = rng.uniform(-3, 3, (n_walls, 2, 2))
    seg[:, 1] += rng.uniform(0.2, 1.0, (n_walls, 2))            # non-zero lengths
    sig = np.where(rng.random((n_walls, 3)) < 0.3, 0.0, rng.uniform(0.001, 0.2, (n_walls, 3)))
    idx = rng.integers(-1, n_walls, (n, k, order))
    t = rng.uniform(-0.3, 1.3, (n, k, order))
    pts = seg[np.maximum(idx, 0), 0] + t[..., None] * (seg[np.maximum(idx, 0), 1]
                                                       - seg[np.maximum(idx, 0), 0])
    pts += rng.normal(0, 0.01, pts.shape)
    pts[idx < 0] = np.nan
    np.testing.assert_allclose(end_weight_rows(seg, sig[:, 1:], idx, pts),
                               end_weights_numpy(seg, sig[:, 1:], idx, pts), rtol=1e-12,
                               atol=1e-15)
    np.testing.assert_allclose(map_sigma_rows(seg, sig, idx, pts),
                               map_sigma_numpy(seg, sig, idx, pts), rtol=1e-12, atol=1e-15)
    # an echo batch hands them slices of wider arrays (read in place): the same numbers
    wide_idx = np.concatenate([idx, np.full_like(idx, -1)], axis=1)[:, :k]
    wide_pts = np.concatenate([pts, np.full_like(pts, np.nan)], axis=1)[:, :k]
    np.testing.assert_array_equal(end_weight_rows(seg, sig[:, 1:], wide_idx, wide_pts),
                                  end_weight_rows(seg, sig[:, 1:], idx, pts))
    np.testing.assert_array_equal(map_sigma_rows(seg, sig, wide_idx, wide_pts),
                                  map_sigma_rows(seg, sig, idx, pts))
    # their parallel twins: the same numbers
    np.testing.assert_array_equal(end_weight_rows(seg, sig[:, 1:], idx, pts, parallel=True),
                                  end_weight_rows(seg, sig[:, 1:], idx, pts))
    np.testing.assert_array_equal(map_sigma_rows(seg, sig, idx, pts, parallel=True),
                                  map_sigma_rows(seg, sig, idx, pts))


def test_floor_and_ceiling_copies_explain_the_ghosts_of_a_3d_room() -> None:
    """A 3-D room (raw simulator, ``vertical_order=2``: every wall path also via the floor
    and the ceiling; 40 kHz, no other effect, so the stream is the run): at the true pose
    the model told the sonar and ceiling heights explains more of the measured peaks and
    scores higher than the 2-D model, which charges the ghosts as clutter; a copy that is
    not among the peaks costs nothing (copies are never expected)."""
    from mapping.heatmap import heatmap_of_run
    from mapping.path import builtin_path
    from mapping.run import Run
    from mapping.scene import builtin_scene
    from mapping.signal import SonarConfig
    from mapping.simulate.ism import IsmConfig
    from mapping.simulate.raw import RawConfig, simulate_raw
    from mapping.wallmap import wallmap_from_walls

    cfg = SonarConfig()
    scene, path = builtin_scene("shoebox"), builtin_path("shoebox-straight")
    raw = RawConfig(fs_hz=cfg.fs_hz, sonar_height_m=0.3, ceiling_height_m=2.6,
                    vertical_order=2)
    n = 4
    rec = simulate_raw(scene, path, cfg, n * cfg.block_s, IsmConfig(max_order=2,
                       max_path_m=12.0), raw, np.random.default_rng(0))
    blocks = rec.samples[: n * cfg.block_samples].reshape(n, -1).astype(np.float32)
    mid = (np.arange(n) + 0.5) * cfg.block_s
    run = Run(config=cfg, samples=blocks, t_s=np.arange(n, dtype=np.float64) * cfg.block_s,
              speed_m_s=path.speed_m_s(mid), yaw_rate_rad_s=path.yaw_rate_rad_s(mid),
              pose=path.pose(mid))
    wm = wallmap_from_walls(scene.segments().reshape(-1, 4),
                            np.abs(scene.reflection_coefficients()))
    flat = SensorConfig(model="echo")
    tall = dataclasses.replace(flat, sonar_height_m=0.3, ceiling_height_m=2.6)
    assert tall.peaks_read == 2 * flat.peaks_read
    for k in (1, 2, 3):
        hm = heatmap_of_run(run, k)
        ex = {}
        for name, cfg_s in (("2d", flat), ("3d", tall)):
            tables = build_tables(wm, cfg_s, sonar=cfg)
            ex[name] = explanation(tables, prepare_measurement(hm, cfg_s), run.pose[k][None])
        assert ex["3d"].explained[0] > ex["2d"].explained[0] + 0.1, (k, ex)
        # same peaks read by the 2-D model with as many peaks: the copies are what helps
        wide = dataclasses.replace(flat, max_peaks=flat.peaks_read * 2)
        tw = build_tables(wm, wide, sonar=cfg)
        ew = explanation(tw, prepare_measurement(hm, wide), run.pose[k][None])
        assert ex["3d"].log_likelihood[0] > ew.log_likelihood[0], (k, ex, ew)
        # levels are compared in 2-D rooms only (floor copies merge with their wall echoes)
        off = build_tables(wm, dataclasses.replace(tall, amplitude_sigma=0.0), sonar=cfg)
        np.testing.assert_array_equal(
            explanation(off, prepare_measurement(hm, tall), run.pose[k][None]).log_likelihood,
            ex["3d"].log_likelihood)


def test_the_echo_model_reads_a_bank_twice_the_maps() -> None:
    assert ECHO.heatmap_sonar(SONAR) == dataclasses.replace(SONAR, directions=58)
    # the G models compare with G, built from the map's own bank; 1 keeps it for the echo model
    assert SensorConfig().heatmap_sonar(SONAR) is SONAR
    assert SensorConfig(model="echo", echo_bank_oversample=1).heatmap_sonar(SONAR) is SONAR
    run = synthetic_run(SONAR, SyntheticWall(1.5, math.radians(60.0)), 0.15, n_blocks=3)
    assert heatmap_run(run, SensorConfig()) is run
    heard = heatmap_run(run, ECHO)
    assert heard.config.directions == 58 and heard.samples is run.samples
    assert heatmap_of_run(heard, 1).H.shape[0] == 59


@pytest.mark.parametrize("deg", [84.0, 87.5, 91.25, 95.0])
def test_the_echo_models_bank_reads_a_broadside_cosine_within_the_refinement_floor(
        deg: float) -> None:
    # Against the analytic echo of one wall near broadside at 0.15 m/s (mapping.synthetic):
    # on the map's 29 rows the parabola between rows pulls the cosine towards the nearest
    # row (tests/mapping/walls/test_walls.py); on the echo model's own bank
    # (SensorConfig.heatmap_sonar) it is read within the refinement's cos_floor (0.006),
    # as one peak: the peak window spans the same angle on either bank, so the denser bank
    # adds no sidelobe peaks.
    run = synthetic_run(SONAR, SyntheticWall(1.5, math.radians(deg)), 0.15, n_blocks=3)
    truth = math.cos(run_truth(run, 1).angle_rad)
    fine = prepare_measurement(heatmap_of_run(heatmap_run(run, ECHO), 1), ECHO)
    coarse = prepare_measurement(heatmap_of_run(run, 1), ECHO)
    assert fine.peaks is not None and coarse.peaks is not None
    near = lambda m: np.flatnonzero(np.abs(m.peaks.r - 1.5) < 0.05)  # noqa: E731
    assert near(fine).size == near(coarse).size == 1
    assert abs(fine.peaks.c[near(fine)[0]] - truth) < 0.006
    assert abs(fine.peaks.c[near(fine)[0]] - truth) <= abs(coarse.peaks.c[near(coarse)[0]] - truth)


def test_the_peak_window_spans_the_same_angle_on_any_bank() -> None:
    from localization.sensor._measurement import peak_angle_window
    for directions, rows in ((29, 2), (58, 4), (87, 6), (10, 1)):
        cfg = dataclasses.replace(SONAR, directions=directions)
        hm = doppler_heatmap(np.random.default_rng(0).normal(size=cfg.block_samples), 0.15, cfg)
        assert peak_angle_window(hm) == rows
