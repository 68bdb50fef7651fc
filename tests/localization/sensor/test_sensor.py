"""Tests of the sensor model: kernels vs twins, FFT vs per-pose scores, geometry truth."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from localization.sensor import (
    Model,
    SensorConfig,
    SensorTables,
    build_tables,
    free_space_mask,
    log_likelihood,
    polar_prediction,
    pose_log_likelihood,
    prepare_measurement,
    score_cells_all_headings,
    score_poses,
    uses_direction,
    validate_block,
)
from localization.sensor._measurement import _bin_ranges as bin_ranges
from mapping.coverage import coverage_mask
from mapping.heatmap import HeatMap
from mapping.wallmap import WallMap, rasterize_walls
from tests.localization.helpers import ASYMMETRIC_ROOM, rasterize, synthetic_heatmap
from tests.localization.sensor.naive import score_poses_numpy

TRUTH = np.array([1.3, 1.1, 0.4])


@pytest.fixture(scope="module")
def tables() -> SensorTables:
    return build_tables(rasterize(ASYMMETRIC_ROOM), SensorConfig(max_range_m=4.5))


@pytest.fixture(scope="module")
def heat_map() -> HeatMap:
    return synthetic_heatmap(ASYMMETRIC_ROOM, TRUTH, 0.2, np.random.default_rng(0))


def _random_poses(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.6, 4.6, n), rng.uniform(-0.6, 3.8, n),
                            rng.uniform(-np.pi, np.pi, n)])


@pytest.mark.parametrize("model", ["correlation", "range"])
def test_kernel_matches_numpy_twin(tables: SensorTables, heat_map: HeatMap, model: Model) -> None:
    m = prepare_measurement(heat_map, dataclasses.replace(tables.config, model=model))
    poses = _random_poses(500, 1)
    a, b = score_poses(tables, m, poses), score_poses_numpy(tables, m, poses)
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_allclose(a[~np.isnan(a)], b[~np.isnan(b)], atol=1e-9)
    assert np.isnan(a).any() and (~np.isnan(a)).any()   # both off- and on-map poses hit


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_scores_are_correlations(tables: SensorTables, seed: int) -> None:
    rng = np.random.default_rng(seed)
    pose = np.array([rng.uniform(0.4, 3.6), rng.uniform(0.4, 2.2), rng.uniform(-3, 3)])
    hm = synthetic_heatmap(ASYMMETRIC_ROOM, pose, rng.uniform(-0.3, 0.3), rng)
    rho = score_poses(tables, prepare_measurement(hm, tables.config), _random_poses(50, seed))
    ok = rho[~np.isnan(rho)]
    assert np.all((ok >= -1 - 1e-9) & (ok <= 1 + 1e-9))


def test_fft_all_headings_equals_per_pose_scores(tables: SensorTables,
                                                 heat_map: HeatMap) -> None:
    """The exhaustive circular correlation is the particle score at cell centres."""
    m = prepare_measurement(heat_map, tables.config)
    cells = np.argwhere(tables.free_mask)[::37]
    rho = score_cells_all_headings(tables, m, cells, chunk=64)
    n_a = tables.config.n_angles
    for k in (0, 5, 40, n_a - 1):
        poses = np.column_stack([tables.origin_m[0] + cells[:, 1] * tables.resolution_m,
                                 tables.origin_m[1] + cells[:, 0] * tables.resolution_m,
                                 np.full(len(cells), 2 * np.pi * k / n_a)])
        np.testing.assert_allclose(rho[:, k], score_poses(tables, m, poses), atol=1e-9)


def test_best_pose_is_the_true_pose(tables: SensorTables, heat_map: HeatMap) -> None:
    """Geometry truth: a fine scan around the room puts the truth (or its exact 2-fold
    image under the mirror fold) first, within 5 cm and 5 deg."""
    m = prepare_measurement(heat_map, tables.config)
    xs, ys = np.arange(0.3, 3.7, 0.05), np.arange(0.3, 2.5, 0.05)
    hs = np.radians(np.arange(-180, 180, 2.5))
    X, Y, H = np.meshgrid(xs, ys, hs, indexing="ij")
    poses = np.column_stack([X.ravel(), Y.ravel(), H.ravel()])
    rho = score_poses(tables, m, poses)
    best = poses[np.nanargmax(rho)]
    assert math.hypot(*(best[:2] - TRUTH[:2])) <= 0.05
    assert abs(math.remainder(best[2] - TRUTH[2], 2 * math.pi)) <= math.radians(5)
    near = score_poses(tables, m, (TRUTH + [[0.15, 0, 0], [0, 0.15, 0], [0, 0, 0.4]]))
    assert np.all(near < score_poses(tables, m, TRUTH[None])[0])


def test_reversing_scores_best_at_the_true_heading(tables: SensorTables) -> None:
    """Reversing: the heat map's angles are from the travel direction (heading + pi); the
    true heading must still beat the flipped one."""
    hm = synthetic_heatmap(ASYMMETRIC_ROOM, TRUTH, -0.2, np.random.default_rng(5))
    m = prepare_measurement(hm, tables.config)
    flipped = TRUTH + [0.0, 0.0, np.pi]
    rho = score_poses(tables, m, np.stack([TRUTH, flipped]))
    assert rho[0] > rho[1] + 0.05


def test_measurement_is_mirror_symmetric(tables: SensorTables, heat_map: HeatMap) -> None:
    """The sensor cannot tell +phi from -phi: the unfolded measurement has that symmetry."""
    m = prepare_measurement(heat_map, tables.config)
    n_a = tables.config.n_angles
    d = m.dense.reshape(tables.n_r, n_a)
    np.testing.assert_allclose(d, d[:, (-np.arange(n_a)) % n_a], atol=1e-12)


def test_range_model_ignores_heading(tables: SensorTables, heat_map: HeatMap) -> None:
    m = prepare_measurement(heat_map, dataclasses.replace(tables.config, model="range"))
    assert m.model == "range"
    poses = np.repeat(TRUTH[None], 36, axis=0)
    poses[:, 2] = np.linspace(-np.pi, np.pi, 36)
    rho = score_poses(tables, m, poses)
    assert np.ptp(rho) == 0.0


@pytest.mark.parametrize("speed", [0.0, 0.01, -0.02])
def test_stationary_uses_range_model(tables: SensorTables, speed: float) -> None:
    hm = synthetic_heatmap(ASYMMETRIC_ROOM, TRUTH, speed, np.random.default_rng(3))
    assert not uses_direction(hm, tables.config)
    assert prepare_measurement(hm, tables.config).model == "range"


def test_polar_prediction_sees_wall_at_its_distance(tables: SensorTables) -> None:
    """G sampled around a pose facing +x at (2, 1): the bottom wall y=0 lies at range 1 m,
    direction -90 deg (a ridge of the rasterized map)."""
    p = polar_prediction(tables, np.array([2.0, 1.0, 0.0]))
    ranges, angles = tables.config.ranges_m, tables.config.angles_rad
    j = int(np.argmin(np.abs(angles + np.pi / 2)))
    assert ranges[int(np.argmax(p[:, j]))] == pytest.approx(1.0, abs=0.05)


def test_log_likelihood_floor_and_order(tables: SensorTables) -> None:
    cfg = tables.config
    rho = np.array([0.3, 0.2, 0.0, -0.5, np.nan])
    ll = log_likelihood(rho, cfg, rho_ref=0.3)
    assert ll[0] == pytest.approx(0.0)
    assert np.all(np.diff(ll[:4]) <= 0)
    assert np.all(ll[:4] >= math.log(cfg.z_rand) - 1e-12)
    assert ll[4] < math.log(cfg.z_rand)


def test_pose_log_likelihood_unfloored_is_beta_rho(tables: SensorTables,
                                                   heat_map: HeatMap) -> None:
    m = prepare_measurement(heat_map, tables.config)
    poses = _random_poses(20, 4)
    rho = score_poses(tables, m, poses)
    ll = pose_log_likelihood(tables, m, poses)
    ok = ~np.isnan(rho)
    np.testing.assert_allclose(ll[ok], tables.config.beta * rho[ok])
    assert np.all(np.isneginf(ll[~ok]))


def test_validate_block() -> None:
    b = 4000
    good = np.random.default_rng(0).standard_normal(b).astype(np.float32)
    validate_block(good, b)
    with pytest.raises(ValueError, match="shape"):
        validate_block(good[:-1], b)
    bad = good.copy()
    bad[10] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        validate_block(bad, b)
    with pytest.raises(ValueError, match="zeros"):
        validate_block(np.zeros(b, np.float32), b)
    with pytest.raises(ValueError, match="clipped"):
        validate_block(np.clip(good * 3, -1, 1), b)


def test_bad_heat_maps_rejected(heat_map: HeatMap) -> None:
    cfg = SensorConfig()
    H = heat_map.H.copy()
    H[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        prepare_measurement(dataclasses.replace(heat_map, H=H), cfg)
    with pytest.raises(ValueError, match="zeros"):
        prepare_measurement(dataclasses.replace(heat_map, H=np.zeros_like(heat_map.H)), cfg)
    with pytest.raises(ValueError, match="axes"):
        prepare_measurement(dataclasses.replace(heat_map, H=heat_map.H[:, :-1]), cfg)


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="n_headings"):
        SensorConfig(n_headings=100)
    with pytest.raises(ValueError, match="z_rand"):
        SensorConfig(z_rand=0.0)
    with pytest.raises(ValueError, match="model"):
        SensorConfig(model="bearing")  # type: ignore[arg-type]


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 10_000))
def test_range_binning_is_the_mean_of_each_bin(seed: int) -> None:
    """Binned columns equal a direct per-bin mean (independent loop), including heat maps
    whose columns reach well past the sensor's max range (prefix sums stop at the last bin)."""
    rng = np.random.default_rng(seed)
    cfg = SensorConfig(max_range_m=float(rng.uniform(1.0, 3.0)))
    ranges_m = np.sort(rng.uniform(0.0, 6.0, int(rng.integers(50, 400))))
    H = rng.random((5, ranges_m.size))
    got = bin_ranges(H, ranges_m, cfg)
    half = 0.5 * cfg.range_step_m
    for k, r in enumerate(cfg.ranges_m):
        sel = (ranges_m >= r - half) & (ranges_m < r + half)
        want = H[:, sel].mean(axis=1) if sel.any() else np.zeros(5)
        np.testing.assert_allclose(got[:, k], want, rtol=1e-9, atol=1e-12)


# ---- free space of a map built from runs -----------------------------------------------------
def _built_like(walls: np.ndarray, path_xy: np.ndarray, radius_m: float = 6.0) -> WallMap:
    """A wall map laid out as :func:`mapping.build.build_map` lays one out: the grid is the
    mapping path's box grown by the back-projection radius, coverage is the path's line of
    sight (:func:`mapping.coverage.coverage_mask`), and provenance names a run."""
    res = 0.05
    lo = path_xy.min(axis=0) - radius_m
    n = np.ceil((path_xy.max(axis=0) + radius_m - lo) / res).astype(int) + 1
    x = lo[0] + res * np.arange(n[0])
    y = lo[1] + res * np.arange(n[1])
    poses = np.column_stack([path_xy, np.zeros(len(path_xy))])
    cov = coverage_mask(poses, x, y, 8.0, walls)
    return WallMap(G=rasterize_walls(walls, x, y).astype(np.float64),
                   origin_m=(float(lo[0]), float(lo[1])), resolution_m=res,
                   method="walls", params={"grid": {"radius_m": radius_m}},
                   provenance={"runs": [{"name": "east"}]}, walls_m=walls, coverage=cov)


def _free_at(wm: WallMap, mask: np.ndarray, x: float, y: float) -> bool:
    ix = int(round((x - wm.origin_m[0]) / wm.resolution_m))
    iy = int(round((y - wm.origin_m[1]) / wm.resolution_m))
    return bool(mask[iy, ix])


def test_free_space_of_a_built_map_is_what_the_runs_saw_inside_their_walls() -> None:
    """A 10 m x 6 m room mapped from a path in its east part, with a partition hiding the
    south-west corner. The robot may stand in the west part (seen, inside the walls, 4 m from
    the path's box): free there, where the path's box plus 1 m (the raster rule, and the rule
    of the same map without runs) says it is not; behind the partition (not seen) and
    outside the room it is never free."""
    room = np.array([[0, 0, 10, 0], [10, 0, 10, 6], [10, 6, 0, 6], [0, 6, 0, 0],
                     [2.5, 0, 2.5, 2.0]], dtype=np.float64)        # the partition: x = 2.5
    path = np.column_stack([np.linspace(7.0, 9.0, 30), np.full(30, 3.0)])
    wm = _built_like(room, path)
    mask = free_space_mask(wm)
    assert _free_at(wm, mask, 4.0, 4.5)                 # west, seen: 3 m beyond the box + 1 m
    assert _free_at(wm, mask, 8.0, 3.0)                 # on the path
    assert not _free_at(wm, mask, 1.2, 0.8)             # behind the partition: never seen
    assert not _free_at(wm, mask, 11.0, 3.0)            # outside the room
    assert not _free_at(wm, mask, 5.0, 0.05)            # on a wall (clearance)
    old = free_space_mask(dataclasses.replace(wm, provenance={}))
    assert not _free_at(wm, old, 4.0, 4.5) and _free_at(wm, old, 8.0, 3.0)


def test_free_space_of_a_built_map_with_collinear_walls_keeps_the_path_box() -> None:
    """Walls that span no area (one corridor side heard) give no hull: the path's box rule."""
    walls = np.array([[0, 0, 10, 0]], dtype=np.float64)
    path = np.column_stack([np.linspace(3.0, 7.0, 30), np.full(30, 1.0)])
    wm = _built_like(walls, path)
    mask = free_space_mask(wm)
    assert _free_at(wm, mask, 5.0, 1.0) and not _free_at(wm, mask, 5.0, 4.5)
