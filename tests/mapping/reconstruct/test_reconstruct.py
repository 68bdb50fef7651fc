"""Inverse reconstruction: adjoint test, back-projection identity, solver, ghost removal."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.grid import GridExtent, GridParams, accumulate
from mapping.quality import evaluate
from mapping.reconstruct import (
    InverseParams,
    Observations,
    backproject_observations,
    build_operator,
    doppler_kappa,
    fista_nonneg_l1,
    free_radii,
    observations_from_heatmaps,
    operator_norm_sq,
    pool_heatmap,
    reconstruct_inverse,
)
from mapping.signal import SonarConfig
from mapping.wallmap import WallMap
from tests.mapping.ideal import ideal_heatmap


def _random_obs(rng: np.random.Generator, K: int = 3, kappa: float = 0.0) -> Observations:
    poses = np.column_stack([rng.uniform(-0.5, 0.5, (K, 2)), rng.uniform(-np.pi, np.pi, K)])
    return Observations(rng.random((K, 8, 30)), poses, 0.05, np.full(K, kappa))


EXT = GridExtent((-0.8, -0.8), (33, 33), 0.05)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), orientations=st.sampled_from([1, 4, 16]),
       kappa=st.sampled_from([0.0, 3.0, 6.0]))
def test_adjoint_identity(seed: int, orientations: int, kappa: float) -> None:
    """<A x, y> = <x, A^T y> for random x, y (forward and adjoint are one operator)."""
    rng = np.random.default_rng(seed)
    obs = _random_obs(rng, kappa=kappa)
    cells = np.sort(rng.choice(EXT.shape[0] * EXT.shape[1], 300, replace=False))
    op = build_operator(obs, EXT, cells, orientations, radius_m=1.2)
    x = rng.standard_normal((orientations, cells.size))
    y = rng.standard_normal(obs.Y.shape)
    lhs = float(np.sum(op.forward(x) * y))
    rhs = float(np.sum(x * op.adjoint(y)))
    assert lhs == pytest.approx(rhs, rel=1e-10, abs=1e-10)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), orientations=st.sampled_from([1, 5, 16]))
def test_adjoint_is_the_paper_backprojection(seed: int, orientations: int) -> None:
    """Without the Doppler spread, sum_o A^T y is the paper's back-projection (eqs. 2-5) of
    the pooled heat maps, computed independently cell by cell."""
    rng = np.random.default_rng(seed)
    obs = _random_obs(rng)
    cells = np.arange(EXT.shape[0] * EXT.shape[1])
    op = build_operator(obs, EXT, cells, orientations, radius_m=1.2)
    back = op.to_map(op.adjoint(obs.Y))
    ref = np.zeros(EXT.shape)
    n_max = obs.n_dirs - 1
    for iy in range(EXT.shape[0]):
        for ix in range(EXT.shape[1]):
            x, y = EXT.origin_m[0] + 0.05 * ix, EXT.origin_m[1] + 0.05 * iy
            for k, (px, py, phi) in enumerate(obs.poses):
                r = np.hypot(x - px, y - py)
                b = int(np.floor(r / 0.05 + 0.5))
                if r > 1.2 or b >= obs.Y.shape[2]:
                    continue
                d = abs((np.arctan2(y - py, x - px) - phi + np.pi) % (2 * np.pi) - np.pi)
                ref[iy, ix] += obs.Y[k, min(int(np.floor(d * n_max / np.pi + 0.5)), n_max), b]
    np.testing.assert_allclose(back, ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(backproject_observations(obs, EXT, 1.2), ref, atol=1e-12)


def test_fista_reaches_kkt_point() -> None:
    rng = np.random.default_rng(1)
    obs = _random_obs(rng, K=2)
    cells = np.arange(0, EXT.shape[0] * EXT.shape[1], 7)
    op = build_operator(obs, EXT, cells, 4, radius_m=1.2)
    lip = operator_norm_sq(op, rng) * 1.05
    lam = 0.05 * float(op.adjoint(obs.Y).max())
    x, hist = fista_nonneg_l1(op, obs.Y, lam, 2000, lip)
    assert hist[-1] < hist[0]
    grad = op.adjoint(op.forward(x) - obs.Y) + lam
    assert np.all(x >= 0)
    assert np.max(np.abs(grad[x > 1e-8])) < 1e-3 * lam * 10  # stationary where positive
    assert np.min(grad[x <= 1e-8]) > -1e-3 * lam * 10  # no descent direction at the bound


def test_pool_and_free_radius_from_an_ideal_wall() -> None:
    pose = np.array([0.0, 0.0, 0.3])
    wall = np.array([[[-3.0, 1.2], [3.0, 1.2]]])
    hm = ideal_heatmap(pose, wall, n_samples=2000)
    Y = pool_heatmap(hm, 0.05, 3.0, "none")
    assert Y.shape == (30, 61)
    assert np.argmax(Y.max(axis=0)) == 24  # 1.2 m / 5 cm
    assert Y.max() == pytest.approx(hm.H.max())
    obs = Observations(Y[None], pose[None], 0.05, np.zeros(1))
    assert free_radii(obs, 0.3, 0.1)[0] == pytest.approx(1.2 - 0.025 - 0.1)
    assert doppler_kappa(0.1, SonarConfig()) == pytest.approx(2 * 0.1 * 1.023 * 1e4 / 340)


def test_inverse_removes_mirror_ghosts_on_a_curved_path() -> None:
    """Two walls seen along a quarter circle (ideal heat maps with the Doppler spread): the
    inverse keeps the walls and has far less ghost energy than the paper's sum."""
    walls = np.array([[[-1.0, 2.0], [3.0, 2.0]], [[2.5, -1.0], [2.5, 2.0]]])
    t = np.linspace(0.0, np.pi / 2, 16)
    poses = np.column_stack([1.2 * np.sin(t) - 0.3, 1.2 - 1.2 * np.cos(t) - 0.5, t])
    cfg = SonarConfig()
    hms = [ideal_heatmap(p, walls, n_samples=1200, kappa=doppler_kappa(0.1, cfg))
           for p in poses]
    grid = GridParams(radius_m=3.5)
    G, ext, _ = accumulate(hms, poses, grid)
    params = InverseParams(iterations=150, doppler_spread=True)
    obs, counts = observations_from_heatmaps(hms, poses, grid, params, config=cfg)
    Gi, info = reconstruct_inverse(obs, ext, grid, params)
    assert counts["blocks_used"] == 16 and info["active_cells"] > 0
    q_paper = evaluate(WallMap(G, ext.origin_m, ext.resolution_m), walls)
    q_inv = evaluate(WallMap(Gi, ext.origin_m, ext.resolution_m), walls)
    assert q_inv.ghost_energy < 0.5 * q_paper.ghost_energy
    assert q_inv.get(0.25).precision > q_paper.get(0.25).precision


def test_occlusion_hides_points_behind_wall_cells() -> None:
    from mapping.reconstruct import occluded

    wall = np.column_stack([np.full(41, 1.0), np.linspace(-1.0, 1.0, 41)])  # x = 1, |y| <= 1
    x = np.array([0.5, 2.0, 2.0, 1.0, 2.0])
    y = np.array([0.0, 0.0, 0.9, 0.5, 3.0])
    hidden = occluded(np.array([0.0, 0.0, 0.0]), x, y, wall, 0.05, 0.2)
    # in front, behind, behind near the end, on the wall, beside (bearing past the wall end)
    assert hidden.tolist() == [False, True, True, False, False]
