"""Tests of localization.posterior: the emcee pose posterior on known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from localization import posterior as post
from localization.motion import predict_mean
from localization.posterior._sampler import (
    _ModePart,  # private: the merge rule is tested on its own
)
from mapping.angles import pose_difference, wrap_angle

FAST = post.PosteriorSettings(n_walkers=24, n_steps=600, max_steps=4000,
                              grid_step_m=0.1, grid_heading_step_rad=math.radians(15))


def gaussian_loglik(mean: np.ndarray, cov: np.ndarray) -> post.LogLikelihood:
    """Log of an unnormalized Gaussian in (x, y, heading), heading difference wrapped."""
    icov = np.linalg.inv(cov)

    def ll(p: np.ndarray) -> np.ndarray:
        d = p - mean
        d[:, 2] = wrap_angle(d[:, 2])
        return -0.5 * np.einsum("ni,ij,nj->n", d, icov, d)

    return ll


def mixture_loglik(parts: list[tuple[float, np.ndarray, np.ndarray]]) -> post.LogLikelihood:
    """Log of sum_k w_k N(mean_k, cov_k) (normalized components, so w_k are the masses)."""
    funcs = [(math.log(w) - 0.5 * math.log(np.linalg.det(2 * np.pi * c)),
              gaussian_loglik(m, c)) for w, m, c in parts]

    def ll(p: np.ndarray) -> np.ndarray:
        return np.logaddexp.reduce(np.stack([a + f(p) for a, f in funcs]), axis=0)

    return ll


def cov3(sx: float, sy: float, sh: float, rho_xy: float = 0.0) -> np.ndarray:
    c = np.diag([sx**2, sy**2, sh**2])
    c[0, 1] = c[1, 0] = rho_xy * sx * sy
    return c


PRIOR = post.PosePrior(0.0, 3.0, 0.0, 4.0)


# ---- the known answer: a Gaussian through the same code path --------------------------
def test_gaussian_mean_and_covariance_match() -> None:
    mean = np.array([1.2, 2.1, 0.4])
    cov = cov3(0.05, 0.08, 0.12, rho_xy=0.6)
    res = post.sample_posterior(gaussian_loglik(mean, cov), PRIOR, np.random.default_rng(3),
                                FAST)
    assert len(res.modes) == 1
    m = res.modes[0]
    sd = np.sqrt(np.diag(cov))
    # tolerances: means within 0.15 sd (~5 standard errors at >= 1000 effective samples),
    # covariance elements within 0.15 sd_i sd_j
    assert np.all(np.abs(m.mean - mean) < 0.15 * sd)
    assert np.all(np.abs(m.cov - cov) < 0.15 * np.outer(sd, sd))
    assert m.converged and res.converged
    assert m.n_steps - m.discard >= FAST.tau_multiple * np.max(m.tau)
    assert 0.15 < m.acceptance_fraction < 0.9
    assert m.mass == pytest.approx(1.0)
    # 68 / 95 % equal-tailed intervals of x against the normal quantiles
    z68, z95 = stats.norm.ppf(0.84), stats.norm.ppf(0.975)
    assert m.interval68[0] == pytest.approx([mean[0] - z68 * sd[0], mean[0] + z68 * sd[0]],
                                            abs=0.2 * sd[0])
    assert m.interval95[0] == pytest.approx([mean[0] - z95 * sd[0], mean[0] + z95 * sd[0]],
                                            abs=0.3 * sd[0])


def test_gaussian_hpd_volume_and_grid_agreement() -> None:
    mean = np.array([1.5, 2.0, -1.0])
    cov = cov3(0.04, 0.04, 0.1)
    res = post.sample_posterior(gaussian_loglik(mean, cov), PRIOR, np.random.default_rng(4),
                                FAST)
    # HPD volume of a 3-D Gaussian: 4/3 pi r^3 sqrt(det C), r^2 the chi2(3) quantile
    for level, vol in zip(res.hpd_levels, res.hpd_volume, strict=True):
        r = math.sqrt(stats.chi2.ppf(level, 3))
        truth = 4.0 / 3.0 * math.pi * r**3 * math.sqrt(np.linalg.det(cov))
        assert vol == pytest.approx(truth, rel=0.15)
    cmp = res.modes[0].comparison
    assert cmp.outside < 0.01
    assert cmp.hellinger < 2.0 * cmp.hellinger_iid + 0.05
    assert cmp.coverage68 == pytest.approx(0.68, abs=0.1)
    assert cmp.coverage95 == pytest.approx(0.95, abs=0.04)


def test_seeded_runs_repeat_exactly() -> None:
    ll = gaussian_loglik(np.array([1.0, 1.0, 0.0]), cov3(0.05, 0.05, 0.1))
    small = post.PosteriorSettings(n_walkers=8, n_steps=50, max_steps=50, grid_step_m=0.2,
                                   grid_heading_step_rad=math.radians(30))
    a = post.sample_posterior(ll, PRIOR, np.random.default_rng(7), small)
    b = post.sample_posterior(ll, PRIOR, np.random.default_rng(7), small)
    c = post.sample_posterior(ll, PRIOR, np.random.default_rng(8), small)
    np.testing.assert_array_equal(a.samples, b.samples)
    assert not np.array_equal(a.samples, c.samples)


# ---- modes -----------------------------------------------------------------------------
def test_mirror_modes_both_found_with_equal_masses() -> None:
    # a hand-made mirror-symmetric likelihood: the pose and its mirror about the line y = 2
    # (heading reflected), as a straight path along a symmetric room gives
    a = np.array([1.5, 1.4, 0.3])
    b = np.array([1.5, 2.6, -0.3])
    c = cov3(0.03, 0.05, 0.08)
    ll = mixture_loglik([(1.0, a, c), (1.0, b, c)])
    res = post.sample_posterior(ll, PRIOR, np.random.default_rng(11), FAST)
    assert len(res.modes) == 2
    means = np.array([m.mean for m in res.modes])
    found = sorted(means.tolist(), key=lambda m: m[1])
    np.testing.assert_allclose(found, [a, b], atol=0.03)
    for m in res.modes:
        assert 0.3 <= m.mass <= 0.7
    assert res.weights.sum() == pytest.approx(1.0)


def test_unequal_mode_masses_recovered() -> None:
    # masses 0.25 / 0.75 with different widths: the fine per-mode grids must integrate them
    a, b = np.array([0.8, 1.0, 2.0]), np.array([2.2, 3.0, -2.5])
    ll = mixture_loglik([(0.25, a, cov3(0.02, 0.03, 0.05)), (0.75, b, cov3(0.06, 0.04, 0.2))])
    res = post.sample_posterior(ll, PRIOR, np.random.default_rng(12), FAST)
    assert len(res.modes) == 2
    big, small = res.modes
    np.testing.assert_allclose(big.mean, b, atol=0.05)
    assert big.mass == pytest.approx(0.75, abs=0.05)
    assert small.mass == pytest.approx(0.25, abs=0.05)
    # pooled weighted samples: P(y > 2) is the big mode's mass
    assert np.sum(res.weights[res.samples[:, 1] > 2.0]) == pytest.approx(0.75, abs=0.05)


def test_heading_near_pi_is_one_mode() -> None:
    truth = np.array([1.0, 2.0, math.pi - 0.03])
    sh = 0.1
    res = post.sample_posterior(gaussian_loglik(truth, cov3(0.04, 0.04, sh)), PRIOR,
                                np.random.default_rng(5), FAST)
    assert len(res.modes) == 1
    m = res.modes[0]
    assert abs(wrap_angle(m.mean[2] - truth[2])) < 0.03
    assert m.heading_circular_std_rad == pytest.approx(sh, rel=0.15)
    assert math.sqrt(m.cov[2, 2]) == pytest.approx(sh, rel=0.15)
    # samples straddle the seam (both signs) yet form one cluster on the circle
    assert np.any(res.samples[:, 2] > 3.0) and np.any(res.samples[:, 2] < -3.0)
    assert m.interval95[2, 1] - m.interval95[2, 0] < 5 * sh


def test_flat_heading_does_not_invent_a_bearing() -> None:
    # a stationary robot: the likelihood ignores heading entirely
    def ll(p: np.ndarray) -> np.ndarray:
        return -0.5 * (((p[:, 0] - 1.0) / 0.05) ** 2 + ((p[:, 1] - 2.0) / 0.05) ** 2)

    s = post.PosteriorSettings(n_walkers=24, n_steps=800, max_steps=3000, grid_step_m=0.1,
                               grid_heading_step_rad=math.radians(30))
    res = post.sample_posterior(ll, PRIOR, np.random.default_rng(6), s)
    assert len(res.modes) == 1
    assert res.modes[0].heading_resultant_length < 0.15
    counts = np.histogram(res.samples[:, 2], bins=6, range=(-np.pi, np.pi))[0]
    assert counts.min() > 0.5 * counts.mean()


def test_grid_modes_wrap_heading_and_merge_shallow_bumps() -> None:
    x = np.linspace(0, 1, 11)
    h = post.full_turn_headings(math.radians(10))
    X, Y, Hd = np.meshgrid(x, x, h, indexing="ij")
    # one peak at heading +-pi (split across the seam of the axis) -> one mode
    lp = -0.5 * (((X - 0.5) / 0.1) ** 2 + ((Y - 0.5) / 0.1) ** 2
                 + (wrap_angle(Hd - np.pi) / 0.2) ** 2)
    grid = post.GridPosterior(x, x, h, lp, periodic=True)
    assert post.find_grid_modes(grid).n_modes == 1
    # a second peak at heading 0 whose saddle is ~31 nats deep: kept at a 3-nat persistence
    # threshold, merged at 50 nats once the valley cells are visited (mass_level=1); within
    # the default 99.9 % region the valley is absent and the two are separate regardless
    lp0 = -0.5 * (((X - 0.5) / 0.1) ** 2 + ((Y - 0.5) / 0.1) ** 2
                  + (wrap_angle(Hd) / 0.2) ** 2) - 1.0
    two = post.GridPosterior(x, x, h, np.maximum(lp, lp0), periodic=True)
    kept = post.find_grid_modes(two, persistence_nats=3.0)
    assert kept.n_modes == 2
    assert kept.mass[0] == pytest.approx(1 / (1 + math.exp(-1.0)), abs=0.01)
    assert abs(kept.peak[0, 2]) == pytest.approx(np.pi, abs=0.1)
    assert post.find_grid_modes(two, persistence_nats=50.0, mass_level=1.0).n_modes == 1
    assert post.find_grid_modes(two, persistence_nats=50.0).n_modes == 2


# ---- window geometry ---------------------------------------------------------------------
@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(-0.3, 0.3), st.floats(-0.5, 0.5)), min_size=1, max_size=6),
       st.floats(-math.pi, math.pi))
def test_window_offsets_match_dead_reckoning(odo: list[tuple[float, float]],
                                             h0: float) -> None:
    v = np.array([o[0] for o in odo])
    w = np.array([o[1] for o in odo])
    block_s = 1.023
    offsets = post.window_offsets(v, w, block_s)
    start = np.array([0.7, -0.2, h0])
    pose = start.copy()
    for k in range(1, v.size):  # second half of block k-1, first half of block k
        pose = predict_mean(pose, v[k - 1], w[k - 1], 0.5 * block_s)
        pose = predict_mean(pose, v[k], w[k], 0.5 * block_s)
        got = post.compose(start[None, :], offsets[k])[0]
        np.testing.assert_allclose(got[:2], pose[:2], atol=1e-9)
        assert abs(wrap_angle(got[2] - pose[2])) < 1e-9
    np.testing.assert_array_equal(offsets[0], 0.0)


def test_window_log_likelihood_sums_blocks_at_odometry_poses() -> None:
    v, w, block_s = np.array([0.1, 0.1, 0.1]), np.array([0.0, 0.3, 0.3]), 1.0
    offsets = post.window_offsets(v, w, block_s)
    truth = np.array([[1.0, 1.0, 0.5]])
    block_truths = [post.compose(truth, o)[0] for o in offsets]
    funcs = [gaussian_loglik(t, cov3(0.05, 0.05, 0.1)) for t in block_truths]
    ll = post.window_log_likelihood(funcs, offsets)
    assert ll(truth)[0] == pytest.approx(0.0, abs=1e-12)
    shifted = truth + np.array([[0.02, 0.0, 0.0]])
    assert ll(shifted)[0] == pytest.approx(-3 * 0.5 * (0.02 / 0.05) ** 2, rel=1e-6)


def test_log_posterior_wraps_heading_and_respects_the_prior() -> None:
    seen: list[np.ndarray] = []

    def ll(p: np.ndarray) -> np.ndarray:
        seen.append(p.copy())
        return np.zeros(p.shape[0])

    theta = np.array([[1.0, 1.0, 3 * np.pi], [5.0, 1.0, 0.0], [1.0, 1.0, -0.5]])
    lp = post.log_posterior(theta, ll, PRIOR)
    assert np.isneginf(lp[1]) and np.isfinite(lp[[0, 2]]).all()
    assert seen[0].shape == (2, 3)
    assert np.all(np.abs(seen[0][:, 2]) <= np.pi)
    windowed = PRIOR.with_heading_center(0.0)
    assert np.isneginf(post.log_posterior(np.array([[1.0, 1.0, 3.5]]), ll, windowed)[0])
    mask = np.zeros((5, 4), dtype=bool)
    mask[2, 1] = True
    masked = post.PosePrior(0, 3, 0, 4, support_mask=mask, support_origin_m=(0.0, 0.0),
                            support_resolution_m=1.0)
    out = masked.log_density(np.array([[1.1, 1.9, 0.0], [2.0, 2.0, 0.0]]))
    assert np.isfinite(out[0]) and np.isneginf(out[1])


# ---- particle filter calibration -----------------------------------------------------------
def test_compare_cloud_detects_over_and_under_confidence() -> None:
    mean = np.array([1.0, 2.0, 0.2])
    cov = cov3(0.05, 0.04, 0.1, rho_xy=0.3)
    res = post.sample_posterior(gaussian_loglik(mean, cov), PRIOR, np.random.default_rng(9),
                                FAST)
    rng = np.random.default_rng(10)
    for scale in (1.0, 0.25, 4.0):
        cloud = rng.multivariate_normal(mean, scale * cov, size=4000)
        cal = post.compare_cloud(res, cloud, truth=mean)
        np.testing.assert_allclose(cal.covariance_ratio, scale, rtol=0.2)
        assert cal.mode == 0
        assert cal.nees_truth is not None and cal.nees_truth < 1.0 / scale + 1.0
    honest = post.compare_cloud(res, rng.multivariate_normal(mean, cov, size=4000))
    assert honest.kl_posterior_to_cloud < 0.05


# ---- errors -----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "name"),
    [({"n_walkers": 5}, "n_walkers"), ({"n_steps": 0}, "n_steps"),
     ({"n_steps": 10, "max_steps": 5}, "max_steps"), ({"de_weight": 1.5}, "de_weight"),
     ({"grid_step_m": 0.0}, "grid_step_m"), ({"compare_bins": 1}, "compare_bins")],
)
def test_bad_settings_name_the_argument(kwargs: dict[str, float], name: str) -> None:
    with pytest.raises(ValueError, match=name):
        post.PosteriorSettings(**kwargs)  # type: ignore[arg-type]


def test_bad_inputs_get_clear_errors() -> None:
    with pytest.raises(ValueError, match="speed_m_s"):
        post.window_offsets(np.array([]), np.array([]), 1.0)
    with pytest.raises(ValueError, match="block_s"):
        post.window_offsets(np.array([0.1]), np.array([0.0]), 0.0)
    with pytest.raises(ValueError, match="block_log_likelihoods"):
        post.window_log_likelihood([], np.zeros((0, 3)))
    with pytest.raises(ValueError, match="x range"):
        post.PosePrior(1.0, 1.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="-inf on every grid cell"):
        post.sample_posterior(lambda p: np.full(p.shape[0], -np.inf), PRIOR,
                              np.random.default_rng(0), FAST)
    with pytest.raises(ValueError, match="particles"):
        post.walkers_from_cloud(np.zeros((3, 2)), None, 8, np.random.default_rng(0))


def test_iter_posterior_reports_progress_then_result() -> None:
    ll = gaussian_loglik(np.array([1.0, 1.0, 0.0]), cov3(0.05, 0.05, 0.1))
    small = post.PosteriorSettings(n_walkers=8, n_steps=30, max_steps=30, grid_step_m=0.2,
                                   grid_heading_step_rad=math.radians(30))
    events = list(post.iter_posterior(ll, PRIOR, np.random.default_rng(1), small))
    assert events[0].stage == "grid"
    steps = [e.step for e in events if e.stage == "sample"]
    assert steps == list(range(1, 31))
    assert events[-1].stage == "done" and events[-1].result is not None
    assert not events[-1].result.converged  # 30 steps are far from 50 tau: reported honestly


# ---- the snooker move (regression: emcee's DESnookerMove is biased) --------------------
@pytest.mark.parametrize(("snooker", "low", "high"), [("corrected", 0.85, 1.15),
                                                      ("emcee", 0.2, 0.6)])
def test_snooker_move_samples_the_right_variance(snooker: str, low: float, high: float) -> None:
    import emcee

    cov = cov3(0.05, 0.08, 0.12, rho_xy=0.6)
    icov = np.linalg.inv(cov)
    moves = post.make_moves(0.0, snooker)  # snooker alone
    sampler = emcee.EnsembleSampler(
        16, 3, lambda p: -0.5 * np.einsum("ni,ij,nj->n", p, icov, p), moves=moves,
        vectorize=True)
    p0 = np.random.default_rng(0).multivariate_normal(np.zeros(3), cov, 16)
    sampler.run_mcmc(emcee.State(p0, random_state=np.random.RandomState(0).get_state()), 1500)
    ratio = np.diag(np.cov(sampler.get_chain(discard=200, flat=True).T)) / np.diag(cov)
    assert np.all((ratio > low) & (ratio < high)), ratio


def test_window_offsets_anchor_rebases_on_any_block() -> None:
    v, w = np.array([0.1, 0.12, 0.1, 0.08]), np.array([0.0, 0.2, -0.1, 0.3])
    first = post.window_offsets(v, w, 1.0)
    start = np.array([[1.0, 2.0, 0.4]])
    poses = np.array([post.compose(start, o)[0] for o in first])
    for anchor in range(4):
        rel = post.window_offsets(v, w, 1.0, anchor=anchor)
        np.testing.assert_allclose(rel[anchor], 0.0, atol=1e-15)
        again = np.array([post.compose(poses[anchor][None, :], o)[0] for o in rel])
        np.testing.assert_allclose(again, poses, atol=1e-12)
    with pytest.raises(ValueError, match="anchor"):
        post.window_offsets(v, w, 1.0, anchor=4)


# ---- the real sensor model (issue 6) on a mirror-symmetric room ---------------------------
@pytest.mark.slow
def test_straight_path_keeps_both_mirror_modes_until_a_turn() -> None:
    """The L-room is symmetric about y = x; a straight window cannot tell a pose from its
    mirror (the heat map only knows |bearing|), a turning window can (yaw sign flips)."""
    from localization.sensor import SensorConfig, build_tables
    from tests.localization.helpers import rasterize, synthetic_heatmap, trajectory

    room = np.array([[[0, 0], [5, 0]], [[5, 0], [5, 2]], [[5, 2], [2, 2]], [[2, 2], [2, 5]],
                     [[2, 5], [0, 5]], [[0, 5], [0, 0]]], dtype=float)
    tables = build_tables(rasterize(room), SensorConfig())
    start = np.array([1.2, 0.8, 0.3])
    mirror = np.array([0.8, 1.2, np.pi / 2 - 0.3])
    prior = post.PosePrior(0.3, 1.7, 0.3, 1.7)  # the corner square: holds both
    s = post.PosteriorSettings(n_walkers=12, n_steps=250, max_steps=600, grid_step_m=0.1,
                               grid_heading_step_rad=math.radians(15), local_grid_cells=15)
    rng = np.random.default_rng(0)
    masses = {}
    for name, w in (("straight", 0.0), ("turn", 0.5)):  # constant yaw rate over the window
        poses = trajectory(start, [(0.1, w)] * 2, 1.023)
        heat = [synthetic_heatmap(room, p, 0.1, rng) for p in poses]
        ll = post.sensor_window_log_likelihood(tables, heat, np.full(3, 0.1), np.full(3, w),
                                               1.023)
        res = post.sample_posterior(ll, prior, np.random.default_rng(1), s)
        near = [min(float(np.linalg.norm(pose_difference(m.mean, t))) for t in (start, mirror))
                for m in res.modes]
        assert max(near) < 0.1
        masses[name] = {("truth" if np.linalg.norm(pose_difference(m.mean, start)) < 0.1
                         else "mirror"): m.mass for m in res.modes}
    assert set(masses["straight"]) == {"truth", "mirror"}
    assert all(0.3 <= m <= 0.7 for m in masses["straight"].values())
    assert masses["turn"].get("truth", 0.0) > 0.95


def test_ensembles_that_meet_are_merged() -> None:
    rng = np.random.default_rng(0)
    run = post.ChainRun(np.zeros((1, 1, 3)), np.zeros((1, 1)), np.ones(4), 0, 1, 0.3, True)
    grid = post.GridPosterior(np.arange(3.0), np.arange(3.0), np.arange(3.0),
                              np.zeros((3, 3, 3)), periodic=False)
    cmp = post.GridComparison(0, 0, 0, 0.68, 0.95, 0, 100)

    def part(center: list[float]) -> _ModePart:
        pts = rng.normal(center, [0.05, 0.05, 0.1], size=(500, 3))
        return _ModePart(run, pts, np.zeros(500), grid, cmp)

    parts = [part([1.0, 1.0, 0.0]), part([1.01, 1.0, 0.02]), part([2.0, 1.0, 0.0])]
    merged, coarse = post.merge_overlapping(parts, np.array([0.3, 0.3, 0.4]))
    assert len(merged) == 2
    assert merged[0].samples.shape[0] == 1000
    np.testing.assert_allclose(coarse, [0.6, 0.4])


# ---- the CLI edge -------------------------------------------------------------------------
def test_cli_posterior_writes_record_and_rejects_bad_arguments(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    from mapping.files import write_map, write_run
    from mapping.signal import SonarConfig
    from mapping.synthetic import Wall, synthetic_run
    from mapping.wallmap import WallMap
    from service.cli import main

    run = synthetic_run(SonarConfig(repetitions=4), Wall(1.0, np.pi / 2), 0.1, n_blocks=2)
    xs, ys = np.arange(-2.0, 2.01, 0.05), np.arange(-1.0, 1.51, 0.05)
    G = np.exp(-0.5 * ((ys[:, None] - 1.0) / 0.035) ** 2) * np.ones((1, xs.size))
    write_map(tmp_path / "map.npz", WallMap(G=G, origin_m=(-2.0, -1.0), resolution_m=0.05))
    write_run(tmp_path / "run.npz", run)
    common = ["posterior", "--map", str(tmp_path / "map.npz"), str(tmp_path / "run.npz"),
              "--out", str(tmp_path / "post.npz")]
    assert main([*common, "--blocks", "0:2", "--walkers", "6", "--steps", "15",
                 "--max-steps", "15", "--png", str(tmp_path / "c.png")]) == 0
    with np.load(tmp_path / "post.npz") as rec:
        assert rec["samples"].shape[1] == 3
        assert rec["weights"].sum() == pytest.approx(1.0)
        assert rec["mode_mass"].sum() == pytest.approx(1.0)
        np.testing.assert_allclose(rec["truth"], run.pose[0])
    assert (tmp_path / "c.png").stat().st_size > 1000
    for bad, name in ((["--blocks", "1:1"], "0 <= A < B <= 2"),
                      (["--blocks", "0:2", "--walkers", "5"], "n_walkers"),
                      (["--blocks", "0:2", "--steps", "0"], "n_steps"),
                      (["--blocks", "x"], "--blocks")):
        capsys.readouterr()
        assert main([*common, *bad]) == 2
        assert name in capsys.readouterr().err


def test_autocorr_check_survives_a_frozen_chain() -> None:
    # regression: a chain whose walkers never moved gave tau = NaN and crashed the CLI
    chain = np.zeros((20, 6, 3))
    chain[:, :, 0] = np.random.default_rng(0).normal(size=(20, 6))
    tau, discard, ok = post.autocorr_check(chain, 50.0)
    assert np.all(np.isfinite(tau)) and tau.max() == 20 - discard and not ok
