"""Tests of circular statistics, covariance, NEES and mode clustering."""

from __future__ import annotations

import math

import numpy as np
import pytest

from localization.estimate import ClusterConfig, find_modes, nees, summarize, weighted_mean_cov
from mapping.angles import pose_error, wrap_angle


def test_covariance_wraps_heading() -> None:
    rng = np.random.default_rng(1)
    n = 20000
    poses = np.column_stack([rng.normal(1, 0.1, n), rng.normal(2, 0.2, n),
                             wrap_angle(math.pi + rng.normal(0, 0.05, n))])
    mean, cov = weighted_mean_cov(poses, np.ones(n))
    assert abs(wrap_angle(mean[2] - math.pi)) < 0.01
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), [0.1, 0.2, 0.05], rtol=0.05)


def test_nees_analytic() -> None:
    cov = np.diag([0.04, 0.01, 0.25])
    e = np.array([0.2, -0.1, 0.5])
    assert nees(np.zeros(3), cov, e) == pytest.approx(0.04 / 0.04 + 0.01 / 0.01 + 0.25 / 0.25)
    assert pose_error(np.array([0, 0, math.pi - 0.1]), np.array([3, 4, -math.pi + 0.1])) == \
        pytest.approx((5.0, 0.2))


def _two_clusters(w1: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    a = np.column_stack([rng.normal(1, 0.03, 500), rng.normal(1, 0.03, 500),
                         rng.normal(0.5, 0.05, 500)])
    b = np.column_stack([rng.normal(3, 0.03, 500), rng.normal(1, 0.03, 500),
                         rng.normal(-2.0, 0.05, 500)])
    w = np.concatenate([np.full(500, w1 / 500), np.full(500, (1 - w1) / 500)])
    return np.vstack([a, b]), w


def test_find_modes_weights_and_means() -> None:
    poses, w = _two_clusters(0.3)
    modes = find_modes(poses, w, ClusterConfig())
    assert len(modes) == 2
    assert modes[0].weight == pytest.approx(0.7)
    assert modes[1].weight == pytest.approx(0.3)
    np.testing.assert_allclose(modes[0].mean[:2], [3, 1], atol=0.01)
    np.testing.assert_allclose(modes[1].mean[:2], [1, 1], atol=0.01)


def test_mode_across_heading_wrap_is_one_mode() -> None:
    rng = np.random.default_rng(4)
    poses = np.column_stack([rng.normal(1, 0.03, 1000), rng.normal(1, 0.03, 1000),
                             wrap_angle(math.pi + rng.normal(0, 0.1, 1000))])
    modes = find_modes(poses, np.ones(1000), ClusterConfig())
    assert len(modes) == 1
    assert modes[0].weight == pytest.approx(1.0)
    assert abs(wrap_angle(modes[0].mean[2] - math.pi)) < 0.02


def _blob(rng: np.random.Generator, x: float, y: float, h: float, n: int, sd_m: float,
          sd_rad: float) -> np.ndarray:
    return np.column_stack([rng.normal(x, sd_m, n), rng.normal(y, sd_m, n),
                            wrap_angle(rng.normal(h, sd_rad, n))])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_near_twins_are_two_modes_not_their_average(seed: int) -> None:
    # a shoebox's mirror twins near its centre line: 0.4 m and 50 deg apart, touching on
    # the coarse grid; their average (heading 0, on the centre line) is neither of them
    rng = np.random.default_rng(seed)
    poses = np.vstack([_blob(rng, 1.57, 1.30, 0.44, 600, 0.02, 0.03),
                       _blob(rng, 1.57, 1.70, -0.44, 400, 0.02, 0.03)])
    modes = find_modes(poses, np.ones(1000), ClusterConfig())
    assert len(modes) == 2
    np.testing.assert_allclose(modes[0].mean, [1.57, 1.30, 0.44], atol=0.02)
    np.testing.assert_allclose(modes[1].mean, [1.57, 1.70, -0.44], atol=0.02)
    assert modes[0].weight == pytest.approx(0.6, abs=0.02)
    # without refinement the coarse grid joins them, as before
    coarse = find_modes(poses, np.ones(1000), ClusterConfig(refine_levels=0))
    assert len(coarse) == 1 and abs(coarse[0].mean[2]) < 0.1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_one_wide_blob_stays_one_mode(seed: int) -> None:
    # a single broad mode (early global start) is not shattered by the refinement
    rng = np.random.default_rng(seed)
    poses = _blob(rng, 2.0, 1.0, 1.0, 2000, 0.25, 0.3)
    modes = find_modes(poses, np.ones(2000), ClusterConfig())
    assert modes[0].weight > 0.8
    np.testing.assert_allclose(modes[0].mean[:2], [2.0, 1.0], atol=0.05)


def test_summarize_converged_flag() -> None:
    poses, w = _two_clusters(0.02)
    est = summarize(poses, np.log(w), ClusterConfig(), ess=10.0, direction_observable=True,
                    updated=True, model="correlation")
    assert est.converged
    assert est.cov_all[0, 0] > est.cov[0, 0]
    poses, w = _two_clusters(0.4)
    est = summarize(poses, np.log(w), ClusterConfig(), ess=10.0, direction_observable=True,
                    updated=True, model="correlation")
    assert not est.converged
    assert len(est.modes) == 2


def test_track_metrics_rmse_all_blocks_by_hand() -> None:
    """Issue 14 item 4: RMSE over every block with truth beside the RMSE after convergence.
    Errors (0.5 m, 0.2 rad), (0.03 m, 0.01 rad), (0.04 m, -0.02 rad), then a block without
    truth: converged from block 1; after it sqrt((0.03^2 + 0.04^2) / 2) m and
    sqrt((0.01^2 + 0.02^2) / 2) rad, over all three sqrt((0.5^2 + 0.03^2 + 0.04^2) / 3) m and
    sqrt((0.2^2 + 0.01^2 + 0.02^2) / 3) rad."""
    from localization.estimate import track_metrics

    truth = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [2.0, 0.0, 1.0],
                      [np.nan, np.nan, np.nan]])
    poses = truth + np.array([[0.3, 0.4, 0.2], [0.0, 0.03, 0.01], [-0.04, 0.0, -0.02],
                              [0.0, 0.0, 0.0]])
    poses[3] = [3.0, 0.0, 0.0]
    covs = np.broadcast_to(np.eye(3) * 0.01, (4, 3, 3))
    m = track_metrics(poses, covs, truth)
    assert m.n_blocks == 3 and m.blocks_to_converge == 1
    assert m.position_rmse_m == pytest.approx(math.sqrt((0.03**2 + 0.04**2) / 2))
    assert m.heading_rmse_rad == pytest.approx(math.sqrt((0.01**2 + 0.02**2) / 2))
    assert m.position_rmse_all_m == pytest.approx(math.sqrt((0.5**2 + 0.03**2 + 0.04**2) / 3))
    assert m.heading_rmse_all_rad == pytest.approx(math.sqrt((0.2**2 + 0.01**2 + 0.02**2) / 3))

    never = track_metrics(poses[:1], covs[:1], truth[:1])       # the one block is 0.5 m off
    assert never.blocks_to_converge is None and math.isnan(never.position_rmse_m)
    assert never.position_rmse_all_m == pytest.approx(0.5)
    assert never.heading_rmse_all_rad == pytest.approx(0.2)


def test_track_status_interim_rule() -> None:
    """``converged`` -> "converged", else "uncertain"; "lost" waits for issue 14 item 2."""
    from localization.estimate import TRACK_STATUSES, track_status

    poses, w = _two_clusters(0.02)
    one = summarize(poses, np.log(w), ClusterConfig(), ess=10.0, direction_observable=True,
                    updated=True, model="correlation")
    poses, w = _two_clusters(0.4)
    two = summarize(poses, np.log(w), ClusterConfig(), ess=10.0, direction_observable=True,
                    updated=True, model="correlation")
    assert (track_status(one), track_status(two)) == ("converged", "uncertain")
    assert TRACK_STATUSES == ("converged", "uncertain", "lost")
