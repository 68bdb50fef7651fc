"""Edge-diffracted paths of the image-source engine (mapping.simulate.ism._diffraction):
delays and path sets against the independent geometry of mapping.compare, continuity across a
reflection boundary, the rendering against a closed form, invariances, edge cases, and one
small FDTD comparison."""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.compare import band_limited, edge_diffraction_paths, residual_energy, retarded
from mapping.path import polyline_path, stationary_path
from mapping.scene import Scene, Wall
from mapping.signal import SonarConfig
from mapping.simulate.ism import (
    IsmConfig,
    diffraction_period,
    edge_delay,
    edge_gains,
    edge_paths,
    edge_validity,
    plan_stretch,
    prepare_scene,
    render_stretch,
    simulate_stretch,
    spreading_power,
)

C = 340.0
SCALED = SonarConfig(sequence_length=31, carrier_hz=2500.0, chip_rate_hz=2500.0,
                     fs_hz=10_000.0, repetitions=2)
ONE_WALL = Scene(name="one wall", walls=[Wall(start=(0.0, 0.5), end=(1.0, 0.5))])
TWO_WALLS = Scene(name="two walls", walls=[Wall(start=(0.0, 0.5), end=(1.0, 0.5)),
                                           Wall(start=(-1.0, -0.5), end=(2.0, -0.5))])
CORNER = Scene(name="corner", walls=[Wall(start=(0.0, 0.0), end=(1.0, 0.0)),
                                     Wall(start=(0.0, 0.0), end=(0.0, 1.0))])


def _static(xy: tuple[float, float]):
    return stationary_path(np.array(xy, dtype=float), 0.0, 10.0)


def _block(scene: Scene, xy: tuple[float, float], order: int, spreading: str = "2d"
           ) -> np.ndarray:
    engine = IsmConfig(order=2, spreading=spreading, diffraction_order=order)
    return simulate_stretch(scene, _static(xy), SCALED, 0, SCALED.block_samples, engine)


@pytest.mark.parametrize("xy", [(-0.3, 0.1), (0.4, 0.0), (1.6, 0.2), (0.5, 0.9)])
def test_path_set_and_delays_equal_the_independent_geometry(xy: tuple[float, float]) -> None:
    """Free ends only (mapping.compare enumerates those): every diffracted path with at most
    one reflection, and its length |S - E| + |E - R| through that reflection, from
    edge_diffraction_paths (specular_path legs, its own occlusion test) equals the set the
    engine renders, with delays to 1e-12 s (static sonar)."""
    seg = TWO_WALLS.segments()
    p = np.array(xy)
    want = sorted(e.length_m for e in edge_diffraction_paths(seg, p, p, [1.0, 0.0], 1)
                  if len(e.walls_in) + len(e.walls_out) <= 1)
    engine = IsmConfig(order=2, diffraction_order=2)
    plan = plan_stretch(prepare_scene(TWO_WALLS, SCALED, engine), _static(xy), SCALED, engine,
                        0, SCALED.block_samples)
    got = sorted(C * plan.edge_tau[:, 2])
    assert len(got) == len(want) >= 2
    assert np.allclose(got, want, atol=C * 1e-12, rtol=0)


@settings(max_examples=25, deadline=None)
@given(st.floats(-1.0, 2.0), st.floats(-0.4, 0.4), st.floats(0, 2 * math.pi),
       st.floats(0.05, 3.0))
def test_moving_delay_solves_the_retarded_equation(x: float, y: float, heading: float,
                                                   speed: float) -> None:
    """Against mapping.compare.retarded (fixed-point iteration on the path length) for the
    edge-alone paths, and the derivative against a central difference."""
    end = (x + 40 * math.cos(heading), y + 40 * math.sin(heading))
    traj = polyline_path([(x, y), end], speed_m_s=speed, name="line")
    paths = edge_paths(ONE_WALL.segments(), 1)
    h = 1e-5
    t = np.array([0.5, 0.5 - h, 0.5 + h])
    tau, dtau = edge_delay(paths, traj, t, C, newton_steps=3)
    for i, edge in enumerate(paths.wedges.point_m[paths.wedge]):
        def length(s: np.ndarray, r: np.ndarray, e: np.ndarray = edge) -> float:
            return float(np.hypot(*(s - e)) + np.hypot(*(r - e)))

        sol = retarded(length, lambda ts: traj.position(np.array([ts]))[0], 0.5, C, n_iter=30)
        assert sol is not None
        assert C * tau[i, 0] == pytest.approx(sol[0], abs=1e-9)
        assert dtau[i, 0] == pytest.approx((tau[i, 2] - tau[i, 1]) / (2 * h), abs=1e-7)


@pytest.mark.parametrize("spreading", ["2d", "3d"])
def test_total_field_is_continuous_across_the_reflection_boundary(spreading: str) -> None:
    """Below the free end (0, 0.5): at x < 0 the wall's echo is gone, at x >= 0 it is there.
    Without diffraction the block jumps by all of it; with it the change over 2 um is below
    1e-3 of the block (UTD: the edge gives minus half the echo on the lit side, plus half in
    the shadow)."""
    for order, bound in ((0, None), (1, 1e-3)):
        a, b = (_block(ONE_WALL, (x, 0.1), order, spreading) for x in (-1e-6, 1e-6))
        change = np.linalg.norm(a - b) / np.linalg.norm(b)
        if bound is None:
            assert change > 0.99
        else:
            assert change < bound


def test_static_rendering_equals_the_closed_form() -> None:
    """A static sonar hears each edge path as ``Re[(c1 S_keller + c2 S_flat) e^{-i w tau}]
    L**-(p + 1/2)``: the kernel's tables, quadrature and spreading against numpy FFTs."""
    xy, spreading = (-0.4, -0.3), "2d"
    engine = IsmConfig(order=1, spreading=spreading, diffraction_order=2)
    prepared = prepare_scene(CORNER, SCALED, engine)
    plan = plan_stretch(prepared, _static(xy), SCALED, engine, 0, SCALED.block_samples)
    assert plan.active.size == 0 and plan.edge_active.size >= 1  # diffraction only
    got = render_stretch(plan, SCALED, engine)
    pos = np.array([xy])
    paths = prepared.edges
    assert paths is not None
    valid = edge_validity(paths, prepared.segments, pos)
    keller, flat = edge_gains(paths, valid, prepared.reflection, pos, SCALED)
    P = SCALED.period_samples
    f = np.fft.rfftfreq(P, 1 / SCALED.fs_hz)
    sk = np.fft.rfft(diffraction_period(SCALED, spreading, True))
    sf = np.fft.rfft(diffraction_period(SCALED, spreading, False))
    tau, _ = edge_delay(paths, _static(xy), np.array([0.0]), C)
    want = np.zeros(P)
    for i in np.flatnonzero(valid[:, 0]):
        spec = (keller[i, 0] * sk + flat[i, 0] * sf) * np.exp(-2j * np.pi * f * tau[i, 0])
        spec[-1] = spec[-1].real
        amp = (C * tau[i, 0]) ** -(spreading_power(spreading) + 0.5)
        want += np.fft.irfft(spec, n=P) * amp
    assert np.max(np.abs(got[:P] - want)) < 1e-5 * np.max(np.abs(want))


@settings(max_examples=12, deadline=None)
@given(st.floats(0, 2 * math.pi), st.floats(-2, 2), st.floats(-2, 2))
def test_rotating_and_shifting_the_scene_with_the_sonar_changes_nothing(
        angle: float, dx: float, dy: float) -> None:
    rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])

    def move(p: Any) -> tuple[float, float]:
        q = rot @ np.asarray(p, float) + (dx, dy)
        return float(q[0]), float(q[1])

    walls = [Wall(start=move(w.start), end=move(w.end)) for w in CORNER.walls]
    for xy in [(-0.4, -0.3), (-0.3, 0.35)]:
        a = _block(CORNER, xy, 2)
        b = _block(Scene(name="moved", walls=walls), move(np.array(xy)), 2)
        assert np.all(np.isfinite(b))
        assert np.linalg.norm(a - b) < 1e-6 * np.linalg.norm(a)


@pytest.mark.parametrize("xy", [(0.0, 0.5), (1.0, 0.5), (-0.5, 0.5), (0.0, 0.1), (0.0, 0.0)])
def test_sonar_at_an_edge_on_a_wall_line_or_a_boundary_is_finite(xy: tuple[float, float]
                                                                 ) -> None:
    for scene in (ONE_WALL, CORNER):
        x = _block(scene, xy, 2)
        assert np.all(np.isfinite(x))


def test_bad_diffraction_order_names_the_field() -> None:
    with pytest.raises(ValueError, match="diffraction_order"):
        IsmConfig(diffraction_order=3)
    with pytest.raises(ValueError, match="order"):
        edge_paths(ONE_WALL.segments(), 0)


def test_outside_corner_level_and_delay_against_the_fdtd() -> None:
    """Static sonar on the 270 deg side of an outside corner where no specular point lies on
    either wall: the FDTD (1 cm grid, scaled signal) hears the corner and the two far ends;
    without diffraction the image-source block is silent (residual energy 1), with it the
    residual energy of FDTD minus image source (no fitted scale) is below 0.4 (the grid's
    dispersion at 13.6 points per wavelength is most of what is left; 0.07 on a 5 mm grid,
    benchmarks/ism_diffraction.py) and the best alignment is within one sample."""
    from mapping.simulate.fdtd import FdtdConfig, simulate_fdtd

    xy = (-0.4, -0.3)
    dx = 0.01
    cfg = FdtdConfig(grid_step_m=dx, time_step_s=0.567 * dx / C, pml_cells=20, margin_m=0.2,
                     warmup_s=0.02)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fdtd = simulate_fdtd(CORNER, _static(xy), SCALED, cfg, n_blocks=1).samples[0]
    fdtd = np.asarray(fdtd, dtype=np.float64)
    engine = IsmConfig(spreading="2d", max_path_m=C * 0.02, diffraction_order=2)
    ism = band_limited(simulate_stretch(CORNER, _static(xy), SCALED, 0, SCALED.block_samples,
                                        engine), SCALED, cfg)
    assert residual_energy(fdtd, 0 * ism) == 1.0
    assert residual_energy(fdtd, ism) < 0.4
    xc = [float(fdtd @ np.roll(ism, k)) for k in range(-3, 4)]
    assert abs(int(np.argmax(xc)) - 3) <= 1
