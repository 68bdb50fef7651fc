"""Forward model of the heat map: hand cases, kernel vs numpy twin, point-spread vs eq. 1,
image-source engine + eq. 1 on every built-in scene, the left/right mirror."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping import synthetic
from mapping.forward import (
    PSF_HALF_WIDTH,
    Echoes,
    ForwardParams,
    WallSet,
    drift_samples,
    echoes,
    echoes_batch,
    heatmap_correlation,
    match_echoes,
    predicted_heatmap,
    psf_tables,
    render_heatmap,
    required_order,
)
from mapping.heatmap import doppler_heatmap, heatmap_of_run
from mapping.path import builtin_path, builtin_path_names, builtin_path_scene
from mapping.scene import builtin_scene, builtin_scene_names
from mapping.signal import SonarConfig
from mapping.simulate import simulate_run
from mapping.simulate.ism import IsmConfig
from tests.mapping.forward.naive import echoes_numpy, render_numpy

CFG = SonarConfig()
CFG2 = SonarConfig(repetitions=2)
C = CFG.sound_speed_m_s


def _walls(*rows: tuple[float, float, float, float]) -> WallSet:
    return WallSet.from_array(np.array(rows, dtype=np.float64))


# ---- hand cases ------------------------------------------------------------------------------
@pytest.mark.parametrize("angle_deg", [0.0, 35.0, 90.0, 150.0])
def test_single_wall_range_angle_amplitude(angle_deg: float) -> None:
    d, heading = 2.5, math.radians(angle_deg)  # wall x = 2.5, normal +x
    walls = _walls((d, -20.0, d, 20.0))
    e = echoes(walls, [0.0, 0.0, heading], 0.0, CFG)
    assert e.k == 1 and e.order[0] == 1 and e.walls[0, 0] == 0
    assert e.range_m[0] == pytest.approx(d, abs=1e-12)
    assert e.angle_rad[0] == pytest.approx(math.radians(angle_deg), abs=1e-9)
    assert e.amplitude[0] == pytest.approx(1.0 / (2 * d))
    assert e.points_m[0, 0] == pytest.approx([d, 0.0])
    assert e.arrival_bearing_rad[0] == pytest.approx(0.0)


def test_single_wall_retarded_range_and_reversing() -> None:
    walls = _walls((3.0, -20.0, 3.0, 20.0))
    v = 0.2
    ahead = echoes(walls, [0.0, 0.0, 0.0], v, CFG)
    # heard at t_c, emitted L / c earlier 3 v L / c... closer-to-first-order: L = 2d / (1 - v/c)
    assert ahead.range_m[0] == pytest.approx(3.0 / (1 - v / C), rel=1e-9)
    assert ahead.angle_rad[0] == pytest.approx(0.0, abs=1e-6)
    back = echoes(walls, [0.0, 0.0, 0.0], -v, CFG)  # reversing: travel points away
    assert back.angle_rad[0] == pytest.approx(math.pi, abs=1e-6)
    assert back.range_m[0] == pytest.approx(3.0 / (1 + v / C), rel=1e-9)


def test_foot_off_segment_and_occlusion_give_no_echo() -> None:
    assert echoes(_walls((2.0, 1.0, 2.0, 3.0)), [0.0, 0.0, 0.0], 0.1, CFG).k == 0
    occluded = _walls((4.0, -5.0, 4.0, 5.0), (2.0, -1.0, 2.0, 1.0))
    e = echoes(occluded, [0.0, 0.0, 0.0], 0.1, CFG, ForwardParams(max_order=1))
    assert e.k == 1 and e.walls[0, 0] == 1


@pytest.mark.parametrize("corner_deg", [90.0, 60.0])
def test_inside_corner_order_two(corner_deg: float) -> None:
    beta = math.radians(corner_deg)
    walls = _walls((0.0, 0.0, 6.0, 0.0), (0.0, 0.0, 6 * math.cos(beta), 6 * math.sin(beta)))
    r, phi = 1.5, beta * 0.4
    pose = [r * math.cos(phi), r * math.sin(phi), 0.3]
    e = echoes(walls, pose, 0.0, CFG)
    second = e.range_m[e.order == 2]
    # image: rotation by 2 beta about the corner -> path |S - R S| = 2 r sin(beta)
    expected = r * math.sin(beta)
    assert second.size >= 1 and np.allclose(second, expected, atol=1e-9)
    # 90 deg: (0, 1) and (1, 0) are the same map, counted once; 60 deg: two rotations
    assert second.size == (1 if corner_deg == 90.0 else 2)


def test_outside_corner_gives_no_order_two() -> None:
    walls = _walls((0.0, 0.0, 4.0, 0.0), (0.0, 0.0, 0.0, 3.0))
    for pose in ([-1.0, -2.0, 0.0], [2.0, -1.5, 1.0], [-1.0, 1.5, 0.0]):
        e = echoes(walls, pose, 0.1, CFG, ForwardParams(max_order=3))
        assert not np.any(e.order >= 2)


def test_parallel_walls_flutter() -> None:
    walls = _walls((-20.0, 0.0, 20.0, 0.0), (-20.0, 2.0, 20.0, 2.0))
    e = echoes(walls, [0.0, 0.7, 0.0], 0.1, CFG)
    flutter = e.order == 2
    assert flutter.sum() == 2  # (0, 1) and (1, 0): distinct images, as the image method
    assert np.allclose(e.range_m[flutter], 2.0, atol=1e-6)
    assert np.allclose(e.angle_rad[flutter], math.pi / 2, atol=1e-9)


def test_mirror_walls_render_the_same_map() -> None:
    left = _walls((-5.0, 1.2, 5.0, 1.2), (3.0, 0.5, 4.0, 2.0))
    right = _walls((-5.0, -1.2, 5.0, -1.2), (3.0, -0.5, 4.0, -2.0))
    a = predicted_heatmap(left, [0.0, 0.0, 0.0], 0.1, CFG2)
    b = predicted_heatmap(right, [0.0, 0.0, 0.0], 0.1, CFG2)
    assert np.allclose(a.H, b.H, atol=1e-12)
    ea, eb = echoes(left, [0, 0, 0], 0.1, CFG2), echoes(right, [0, 0, 0], 0.1, CFG2)
    assert np.allclose(ea.arrival_bearing_rad, -eb.arrival_bearing_rad)  # the side differs


def test_speed_zero_rows_equal_and_not_observable() -> None:
    hm = predicted_heatmap(_walls((2.0, -3.0, 2.0, 3.0)), [0, 0, 0.4], 0.0, CFG2)
    assert not hm.direction_observable
    assert np.allclose(hm.H, hm.H[:1])


def test_validation_names_the_field() -> None:
    with pytest.raises(ValueError, match="segments_m"):
        WallSet(np.zeros((1, 2, 3)), np.ones(1))
    with pytest.raises(ValueError, match="strength"):
        WallSet(np.array([[[0.0, 0.0], [1.0, 0.0]]]), np.ones(2))
    with pytest.raises(ValueError, match="max_order"):
        ForwardParams(max_order=5)
    with pytest.raises(ValueError, match="spreading"):
        ForwardParams(spreading="1d")
    with pytest.raises(ValueError, match="pose"):
        echoes(_walls((1, 0, 1, 1)), [0, 0], 0.1, CFG)
    with pytest.raises(ValueError, match="speed_m_s"):
        echoes(_walls((1, 0, 1, 1)), [0, 0, 0], math.nan, CFG)
    assert echoes(WallSet.from_array(np.zeros((0, 4))), [0, 0, 0], 0.1, CFG).k == 0


def test_batch_equals_single_and_required_order() -> None:
    walls = WallSet.from_scene(builtin_scene("shoebox"))
    poses = np.array([[1.0, 1.0, 0.3], [2.5, 2.0, -1.0], [3.0, 0.7, 2.0]])
    batch = echoes_batch(walls, poses, 0.1, CFG, ForwardParams(max_order=3))
    for i, pose in enumerate(poses):
        one = echoes(walls, pose, 0.1, CFG, ForwardParams(max_order=3))
        got = batch.echoes_of(i)
        assert np.array_equal(got.walls, one.walls)
        assert np.allclose(got.range_m, one.range_m) and np.allclose(got.amplitude, one.amplitude)
    assert required_order(_walls((3.0, -9.0, 3.0, 9.0)), poses, 0.1, CFG) == 1
    assert required_order(walls, poses, 0.1, CFG) >= 3  # a closed rigid room rings
    serial = echoes_batch(walls, poses, 0.1, CFG, ForwardParams(max_order=3), parallel=False)
    for name in ("count", "range_m", "cos_doppler", "amplitude", "order", "walls", "points_m"):
        np.testing.assert_array_equal(getattr(serial, name), getattr(batch, name), err_msg=name)


def test_poses_beyond_the_first_capacity_are_traced_again_with_room_for_all() -> None:
    """A batch where some poses hear more paths than the kernel's first pass has slots for
    (:data:`mapping.forward._echoes.FIRST_CAPACITY`) and some fewer: every row equals the pose
    traced alone with room for all its paths (the numpy twin's count), none is cut short."""
    from mapping.forward._echoes import FIRST_CAPACITY

    walls = WallSet.from_scene(builtin_scene("shoebox"))
    params = ForwardParams(max_order=3, max_range_m=8.0)
    # the room's middle hears many order-3 paths; outside it (one wall in view) hears one
    poses = np.array([[2.0, 1.5, 0.3], [30.0, 1.5, 0.0], [1.0, 1.0, -1.0], [30.0, -2.0, 1.0]])
    batch = echoes_batch(walls, poses, 0.2, CFG, params)
    want = [len(echoes_numpy(walls.segments_m, walls.strength, p, 0.2, C, 3, 16.0, 1.0))
            for p in poses]
    assert max(want) > FIRST_CAPACITY >= min(want)
    assert list(batch.count) == want
    for i, pose in enumerate(poses):
        one = echoes(walls, pose, 0.2, CFG, params)
        got = batch.echoes_of(i)
        assert got.k == want[i]
        np.testing.assert_array_equal(got.walls, one.walls)
        np.testing.assert_allclose(got.range_m, one.range_m)
        assert np.all(np.diff(got.range_m) >= 0)   # sorted after the merge
        assert np.all(np.isnan(batch.range_m[i, want[i]:]))   # padded beyond its count


# ---- kernel vs numpy twin -------------------------------------------------------------------
@st.composite
def _scenes(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int]:
    n = draw(st.integers(1, 5))
    coords = st.floats(-4.0, 4.0, allow_nan=False)
    rows = []
    for _ in range(n):
        x0, y0 = draw(coords), draw(coords)
        ang, length = draw(st.floats(0, math.pi)), draw(st.floats(0.5, 6.0))
        rows.append([x0, y0, x0 + length * math.cos(ang), y0 + length * math.sin(ang)])
    strength = np.array([draw(st.floats(-1.0, 1.0)) for _ in range(n)])
    pose = np.array([draw(coords), draw(coords), draw(st.floats(-math.pi, math.pi))])
    return np.array(rows), strength, pose, draw(st.floats(-0.3, 0.3)), draw(st.integers(1, 3))


@settings(max_examples=60, deadline=None)
@given(_scenes())
def test_kernel_matches_numpy_twin(case: tuple[np.ndarray, np.ndarray, np.ndarray, float, int]
                                   ) -> None:
    rows, strength, pose, speed, order = case
    walls = WallSet.from_array(rows, strength)
    got = echoes(walls, pose, speed, CFG, ForwardParams(max_order=order, max_range_m=8.0))
    want = echoes_numpy(walls.segments_m, walls.strength, pose, speed, C, order, 16.0, 1.0)
    _assert_twin(got, want)


def _assert_twin(got: Echoes, want: list[dict[str, object]]) -> None:
    """The kernel's echoes are the numpy twin's, one for one."""
    assert got.k == len(want)
    # a path and its reverse have equal lengths at speed 0: the two sorts may order such ties
    # differently in the last bit, so pair each twin echo with the kernel echo of its walls
    used: set[int] = set()
    for w in want:
        ties = [j for j in range(got.k) if j not in used
                and abs(got.range_m[j] - float(w["path_m"]) / 2) < 1e-9  # type: ignore[arg-type]
                and list(got.walls[j, : got.order[j]]) == w["walls"]]
        assert ties, f"no kernel echo for walls {w['walls']}"
        i = ties[0]
        used.add(i)
        assert got.cos_doppler[i] == pytest.approx(w["cos_doppler"], abs=1e-9)
        assert got.amplitude[i] == pytest.approx(w["amplitude"], rel=1e-9)
        assert np.allclose(got.points_m[i, : got.order[i]], np.asarray(w["points"]), atol=1e-9)


def _column_room() -> WallSet:
    """A 7 m x 5 m room with a free-standing octagonal column 0.6 m across (short walls, of
    which most sequences end off the segment or behind the column)."""
    room = [(0.0, 0.0, 7.0, 0.0), (7.0, 0.0, 7.0, 5.0), (7.0, 5.0, 0.0, 5.0), (0.0, 5.0, 0.0, 0.0)]
    a = np.radians(22.5 + 45.0 * np.arange(9))
    ring = np.column_stack([4.2 + 0.3 * np.cos(a), 2.3 + 0.3 * np.sin(a)])
    column = [(*ring[k], *ring[k + 1]) for k in range(8)]
    return WallSet.from_array(np.array(room + column, dtype=np.float64))


@settings(max_examples=25, deadline=None)
@given(st.floats(0.4, 6.6), st.floats(0.4, 4.6), st.floats(-math.pi, math.pi),
       st.floats(-0.3, 0.3))
def test_kernel_matches_numpy_twin_round_a_column(x: float, y: float, heading: float,
                                                  speed: float) -> None:
    """Many short walls (the kernel skips the sequences whose last bounce falls off its
    wall before composing them): the kernel's order-2 echoes equal the numpy twin's, which
    traces every sequence."""
    walls = _column_room()
    pose = np.array([x, y, heading])
    got = echoes(walls, pose, speed, CFG, ForwardParams(max_order=2, max_range_m=8.0))
    _assert_twin(got, echoes_numpy(walls.segments_m, walls.strength, pose, speed, C, 2, 16.0,
                                   1.0))


def test_render_kernel_matches_numpy_twin() -> None:
    walls = _walls((2.0, -3.0, 2.0, 3.0), (-1.0, 1.5, 3.0, 2.5), (-3.0, -2.0, 1.0, -1.0))
    # first order only: no path/reverse pairs, which the incoherent sum merges first
    e = echoes(walls, [0, 0, 0.3], 0.1, CFG2, ForwardParams(max_order=1))
    assert e.k == 3
    psf = psf_tables(CFG2)
    corr = psf.corr_re + 1j * psf.corr_im
    drift = drift_samples(e.cos_doppler, CFG2.angles_rad, 0.1, CFG2)
    lag = e.range_m / CFG2.range_per_sample_m
    for coherent in (False, True):
        got = render_heatmap(e, 0.1, CFG2, coherent=coherent).H
        want = render_numpy(corr, psf.up, drift, lag, e.amplitude, PSF_HALF_WIDTH, coherent,
                            CFG2.period_samples)
        assert np.abs(got - want).max() < 2e-3 * want.max()


# ---- point-spread vs eq. 1 on an exact synthetic echo --------------------------------------
@pytest.mark.parametrize(("speed", "normal_deg"), [(0.1, 40.0), (0.05, 137.0), (0.1, 90.0)])
def test_point_spread_matches_doppler_heatmap(speed: float, normal_deg: float) -> None:
    run = synthetic.synthetic_run(CFG, synthetic.Wall(3.0, math.radians(normal_deg)), speed,
                                  n_blocks=3, spreading=False)
    measured = heatmap_of_run(run, 1)
    pose = run.pose[1]
    n = np.array([math.cos(pose[2] + math.radians(normal_deg)),
                  math.sin(pose[2] + math.radians(normal_deg))])
    foot, t = pose[:2] + 3.0 * n, np.array([-n[1], n[0]])
    walls = WallSet.from_array([[*(foot - 50 * t), *(foot + 50 * t)]])
    e = echoes(walls, pose, speed, CFG)
    unit = Echoes(e.range_m, e.cos_doppler, e.angle_rad, np.ones(1), e.order, e.walls,
                  e.points_m, e.arrival_bearing_rad)
    rendered = render_heatmap(unit, speed, CFG)
    peak = measured.H.max()
    assert rendered.H.max() == pytest.approx(peak, rel=2e-3)
    # near the echo (the PSF window) within 1 % of the peak in rows the bank nearly matches
    drift = drift_samples(e.cos_doppler, CFG.angles_rad, speed, CFG)[:, 0]
    lag = e.range_m[0] / CFG.range_per_sample_m
    cols = np.arange(CFG.period_samples)
    for row in np.flatnonzero(np.abs(drift) < 20):
        near = np.abs(cols - lag) <= abs(drift[row]) / 2 + PSF_HALF_WIDTH
        err = np.abs(rendered.H[row, near] - measured.H[row, near]).max()
        assert err < 0.01 * peak
    # everywhere: the Doppler-mismatch floor (~1/sqrt(L)) is the only thing left out
    assert np.abs(rendered.H - measured.H).max() < 0.05 * peak


# ---- image-source engine + eq. 1 on every built-in scene ------------------------------------
def _scene_paths() -> list[str]:
    names = builtin_path_names()
    return [next(n for n in names if builtin_path_scene(n) == s and "curve" in n)
            if any(builtin_path_scene(n) == s and "curve" in n for n in names)
            else next(n for n in names if builtin_path_scene(n) == s)
            for s in builtin_scene_names()]


def _doppler_resolution(speed: float, config: SonarConfig) -> float:
    """Doppler-cosine step whose drift over the block turns the carrier by 1/2 rad (the
    row's response drops ~1 %): ``D = 2 v dcos B / c`` samples, phase ``2 pi f_c D / f_s``."""
    drift = 0.5 * config.fs_hz / (2 * math.pi * config.carrier_hz)
    return drift * config.sound_speed_m_s / (2 * abs(speed) * config.block_samples)


@pytest.mark.parametrize("path_name", _scene_paths())
def test_forward_model_matches_image_sources_and_eq1(path_name: str) -> None:
    scene = builtin_scene(builtin_path_scene(path_name))
    trajectory = builtin_path(path_name)
    k = int(trajectory.duration_s / CFG2.block_s) // 2
    run = simulate_run(scene, trajectory, CFG2, k + 2, IsmConfig(order=2),
                       np.random.default_rng(0))
    measured = heatmap_of_run(run, k)
    walls = WallSet.from_scene(scene)
    e = echoes(walls, run.pose[k], run.speed_m_s[k], CFG2)
    strong = e.amplitude >= 0.1 * e.amplitude.max()
    assert match_echoes(e, measured, cos_tolerance=_doppler_resolution(run.speed_m_s[k], CFG2)
                        )[strong].all()
    rendered = render_heatmap(e, run.speed_m_s[k], CFG2)
    assert heatmap_correlation(rendered, measured) > 0.7


def test_doppler_heatmap_of_rendered_axes_agree() -> None:
    hm = doppler_heatmap(np.zeros(CFG2.block_samples), 0.1, CFG2)
    r = predicted_heatmap(_walls((2, -1, 2, 1)), [0, 0, 0], 0.1, CFG2)
    assert np.array_equal(hm.angles_rad, r.angles_rad) and np.array_equal(hm.ranges_m, r.ranges_m)
    assert hm.H.shape == r.H.shape and hm.direction_observable == r.direction_observable
