"""Peer cross-check: the image-source engine against pyroomacoustics (issue 15, item 3).

pyroomacoustics is a test-only dependency (the ``peer`` extra); without it this module is
reported as skipped. Its 2-D rooms are built from corners (``Room.from_corners``) or, for the
pillar room, from a wall list whose column walls are obstructing walls. At speed 0 a
monostatic path is an image source seen from the source itself, a point pyroomacoustics treats
as degenerate, so its microphone sits 1 mm from the source. pyroomacoustics stores its
geometry in float32: image positions agree to ~1 ulp at 10-16 m (1e-6 m), delays to a few ns.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from mapping.path import stationary_path
from mapping.scene import Scene, builtin_scene
from mapping.signal import SonarConfig, transmitted_at
from mapping.simulate.ism import (
    IsmConfig,
    candidate_images,
    path_table,
    plan_stretch,
    prepare_scene,
    render_stretch,
    trace_images,
)

pra = pytest.importorskip(
    "pyroomacoustics",
    reason="pyroomacoustics (the peer extra: pip install -e '.[peer]') is not installed",
)

ORDER = 3
POSITION_TOL_M = 2e-6  # float32 images: 1 ulp is 9.5e-7 m between 8 and 16 m
MIC_OFFSET_M = np.array([1e-3, 0.0])
CFG = SonarConfig(repetitions=1)
# generic positions: off the symmetry lines where two image maps coincide (tested apart)
POSITIONS = {
    "shoebox": [(1.13, 0.71), (2.9, 2.2), (0.4, 1.7), (3.3, 0.37), (1.9, 1.45)],
    "l-room": [(4.2, 0.6), (1.0, 4.1), (0.7, 0.9), (3.1, 1.3), (1.4, 2.7)],
    "pillar": [(1.1, 0.8), (4.1, 3.2), (0.63, 2.07), (3.7, 1.1), (2.41, 3.37)],
}


def _scene(name: str, rigid: bool) -> Scene:
    scene = builtin_scene(name)
    if rigid:
        return scene
    refl = np.linspace(0.95, 0.55, len(scene.walls))  # a different R per wall
    walls = [w.model_copy(update={"reflection": float(r)})
             for w, r in zip(scene.walls, refl, strict=True)]
    return Scene(name=scene.name, walls=walls)


def _peer_room(scene: Scene) -> Any:
    """The scene as a pyroomacoustics 2-D room (energy absorption 1 - R**2 per wall)."""
    seg = scene.segments()
    materials = [pra.Material(1.0 - r**2) for r in scene.reflection_coefficients()]
    options = dict(fs=16000, max_order=ORDER, ray_tracing=False, air_absorption=False)
    if scene.name != "pillar":
        return pra.Room.from_corners(seg[:, 0].T, materials=materials, **options)
    # the column: its walls clockwise, so that every wall normal points away from the air
    # (pyroomacoustics reflects only on a wall's front side); they are obstructing walls
    order = [0, 1, 2, 3, 7, 6, 5, 4]
    walls = [pra.wall_factory(seg[i][::-1].T if i >= 4 else seg[i].T,
                              materials[i].absorption_coeffs, [0.0], f"wall_{i}")
             for i in order]
    return pra.Room(walls, **options)


def _peer_paths(scene: Scene, xy: np.ndarray) -> tuple[np.ndarray, ...]:
    """pyroomacoustics' visible image sources: positions (n, 2), orders, reflection products."""
    room = _peer_room(scene)
    room.add_source(xy.tolist())
    room.add_microphone((xy + MIC_OFFSET_M).tolist())
    room.image_source_model()
    src = room.sources[0]
    keep = room.visibility[0][0].astype(bool) & (src.orders > 0)  # order 0: the direct path
    return (src.images.T[keep].astype(np.float64), src.orders[keep].astype(np.int64),
            src.damping[0][keep].astype(np.float64))


def _our_paths(scene: Scene, xy: np.ndarray) -> tuple[np.ndarray, ...]:
    seg, pos = scene.segments(), xy[None]
    images = candidate_images(seg, pos, ORDER)
    trace = trace_images(images, seg, scene.reflection_coefficients(), pos)
    ok = trace.valid[:, 0]
    return images.positions(pos)[ok, 0], trace.order[ok, 0], trace.reflection[ok, 0]


def _match(ours: np.ndarray, peer: np.ndarray, tol: float = POSITION_TOL_M) -> np.ndarray:
    """Index of the peer row for each of ours (one to one); asserts they agree within tol."""
    assert len(ours) == len(peer), (len(ours), len(peer))
    dist = np.linalg.norm(ours[:, None] - peer[None], axis=2)
    i, j = linear_sum_assignment(dist)
    assert np.max(dist[i, j], initial=0.0) < tol, np.max(dist[i, j])
    return np.asarray(j[np.argsort(i)])


CASES = [(name, rigid) for name in POSITIONS for rigid in (True, False)]
IDS = [f"{name}-{'rigid' if rigid else 'absorbing'}" for name, rigid in CASES]


@pytest.mark.parametrize(("name", "rigid"), CASES, ids=IDS)
def test_path_sets_orders_and_reflections_equal_the_peers(name: str, rigid: bool) -> None:
    scene = _scene(name, rigid)
    for xy in np.array(POSITIONS[name]):
        points, order, refl = _our_paths(scene, xy)
        peer_points, peer_order, peer_refl = _peer_paths(scene, xy)
        for k in range(1, ORDER + 1):  # order by order, multiplicity included
            assert np.sum(order == k) == np.sum(peer_order == k), (xy, k)
        j = _match(points, peer_points)
        assert np.array_equal(order, peer_order[j]), xy
        assert np.allclose(refl, peer_refl[j], atol=1e-6, rtol=0), xy  # float32 damping


@pytest.mark.parametrize("name", list(POSITIONS))
def test_rendered_delays_and_waveform_match_the_peers_paths(name: str) -> None:
    """The engine at speed 0 (path table and samples) against the peer's path set rendered
    by hand: delay |image - x| / c (pyroomacoustics' float32 images), 1/r spreading."""
    scene = _scene(name, rigid=False)
    engine = IsmConfig(order=ORDER)
    prepared = prepare_scene(scene, CFG, engine)
    c = CFG.sound_speed_m_s
    t = np.arange(CFG.block_samples) / CFG.fs_hz
    for xy in np.array(POSITIONS[name][:3]):
        traj = stationary_path(xy, math.pi / 4, 30.0)
        plan = plan_stretch(prepared, traj, CFG, engine, 0, CFG.block_samples)
        table = path_table(plan, prepared, traj, CFG, engine)
        peer_points, peer_order, peer_refl = _peer_paths(scene, xy)
        peer_delay = np.linalg.norm(peer_points - xy, axis=1) / c
        # pair the paths by (delay in ns, reflection product): within 6 ns and 1e-6
        j = _match(np.column_stack([table.delay_s / 6e-9, table.reflection / 1e-6]),
                   np.column_stack([peer_delay / 6e-9, peer_refl / 1e-6]), tol=1.0)
        assert np.array_equal(table.order, peer_order[j])
        want = sum(r * transmitted_at(t - tau, CFG) / (c * tau)
                   for r, tau in zip(peer_refl, peer_delay, strict=True))
        got = render_stretch(plan, CFG, engine)
        corr = float(got @ want / (np.linalg.norm(got) * np.linalg.norm(want)))
        assert corr > 1.0 - 1e-6, (xy, corr)


@pytest.mark.parametrize(("name", "xy"), [("l-room", (3.0, 0.7)), ("pillar", (0.6, 2.1))])
def test_coincident_image_maps_give_one_path(name: str, xy: tuple[float, float]) -> None:
    """Regression (issue 15): where two distinct maps send the robot to the same point (L-room
    x = 3: x - 6 = -x; pillar x = 0.6: x - 1.2 = -x) the one physical path was counted twice."""
    scene = _scene(name, rigid=True)
    points, _, _ = _our_paths(scene, np.array(xy))
    peer_points, _, _ = _peer_paths(scene, np.array(xy))
    assert len(points) == len(peer_points)
