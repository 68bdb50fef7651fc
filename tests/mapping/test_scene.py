"""Scenes: JSON round trip, validation messages, reflection from impedance, built-in geometry."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mapping.scene import (
    PAPER_WALL3_X0_M,
    PAPER_WALL3_Y_M,
    Scene,
    Wall,
    builtin_scene,
    builtin_scene_names,
    reflection_from_impedance,
)

RHO_C = 1.293 * 340.0


def _scene_json(walls: list[dict]) -> str:
    return json.dumps({"name": "t", "walls": walls})


def _nearest_on_segment(p: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, float]:
    a, b = seg
    lam = float(np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0))
    q = a + lam * (b - a)
    return q, float(np.linalg.norm(p - q))


@pytest.mark.parametrize("name", builtin_scene_names())
def test_builtin_json_round_trip(name: str) -> None:
    scene = builtin_scene(name)
    again = Scene.from_json(scene.to_json())
    assert again == scene
    np.testing.assert_array_equal(again.segments(), scene.segments())
    np.testing.assert_array_equal(again.reflection_coefficients(), scene.reflection_coefficients())


def test_round_trip_keeps_rigid_impedance_and_medium() -> None:
    scene = Scene(
        name="mix", rho_kg_m3=1.2, sound_speed_m_s=343.0,
        walls=[Wall(start=(0, 0), end=(1, 0), impedance_pa_s_m=math.inf, name="rigid"),
               Wall(start=(1, 0), end=(1, 1), impedance_pa_s_m=2000.0),
               Wall(start=(1, 1), end=(0, 1), reflection=-0.5)],
    )
    text = scene.to_json()
    assert '"inf"' in text
    again = Scene.from_json(text)
    assert again == scene
    np.testing.assert_allclose(
        again.reflection_coefficients(),
        [1.0, (2000.0 - 1.2 * 343.0) / (2000.0 + 1.2 * 343.0), -0.5], rtol=1e-15)


def test_reflection_from_impedance_limits() -> None:
    assert reflection_from_impedance(math.inf, RHO_C) == 1.0
    assert reflection_from_impedance(RHO_C, RHO_C) == 0.0
    assert reflection_from_impedance(0.0, RHO_C) == -1.0
    # independent form: R = (zeta - 1) / (zeta + 1) with zeta = Z / (rho c)
    assert reflection_from_impedance(3 * RHO_C, RHO_C) == pytest.approx(0.5, abs=1e-15)
    with pytest.raises(ValueError, match="impedance_pa_s_m"):
        reflection_from_impedance(-1.0, RHO_C)


def test_wall_reflection_defaults_and_scene_medium() -> None:
    assert Wall(start=(0, 0), end=(1, 0)).reflection_coefficient == 1.0
    w = Wall(start=(0, 0), end=(1, 0), impedance_pa_s_m=RHO_C)
    assert w.reflection_coefficient == pytest.approx(0.0, abs=1e-15)
    # the scene's rho c governs its walls; the Wall object passed in is not modified
    scene = Scene(name="w", walls=[w], rho_kg_m3=2 * 1.293)
    assert scene.walls[0].reflection_coefficient == pytest.approx(-1 / 3, rel=1e-12)
    assert w.reflection_coefficient == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_allclose(scene.reflection_coefficients(), [-1 / 3], rtol=1e-12)
    # an updated copy of the scene uses its own medium
    thin = scene.model_copy(update={"rho_kg_m3": 1.293})
    np.testing.assert_allclose(thin.reflection_coefficients(), [0.0], atol=1e-15)


def test_json_accepts_inf_string() -> None:
    s = Scene.from_json(_scene_json([{"start": [0, 0], "end": [1, 0], "impedance_pa_s_m": "inf"}]))
    assert s.reflection_coefficients()[0] == 1.0


@pytest.mark.parametrize(
    ("wall", "field", "fragment"),
    [
        ({"name": "north", "start": [1, 1], "end": [1, 1]}, "zero-length", "north"),
        ({"name": "east", "start": [float("nan"), 0], "end": [1, 0]}, "start", "east"),
        ({"name": "west", "start": [0, 0], "end": [float("inf"), 0]}, "end", "west"),
        ({"name": "glass", "start": [0, 0], "end": [1, 0], "reflection": 1.2}, "reflection",
         "glass"),
        ({"name": "foam", "start": [0, 0], "end": [1, 0], "impedance_pa_s_m": -5},
         "impedance_pa_s_m", "foam"),
        ({"name": "both", "start": [0, 0], "end": [1, 0], "reflection": 0.5,
          "impedance_pa_s_m": 100}, "not both", "both"),
        ({"name": "typo", "start": [0, 0], "end": [1, 0], "reflexion": 0.5}, "reflexion", "typo"),
    ],
)
def test_validation_names_wall_and_field(wall: dict, field: str, fragment: str) -> None:
    good = {"name": "ok", "start": [0, 0], "end": [0, 1]}
    with pytest.raises(ValueError) as info:
        Scene.from_json(_scene_json([good, wall]))
    msg = str(info.value)
    assert "walls[1]" in msg
    assert fragment in msg
    assert field in msg


def test_validation_of_scene_level_fields() -> None:
    with pytest.raises(ValueError, match="at least one wall"):
        Scene.from_json(_scene_json([]))
    with pytest.raises(ValueError, match="sound_speed_m_s"):
        Scene.from_json(json.dumps({"name": "x", "sound_speed_m_s": -1,
                                    "walls": [{"start": [0, 0], "end": [1, 0]}]}))
    with pytest.raises(ValueError, match="not valid JSON"):
        Scene.from_json("{")


def test_unknown_builtin_names_the_choices() -> None:
    with pytest.raises(ValueError, match="shoebox"):
        builtin_scene("nope")


def test_arrays_and_bounds() -> None:
    s = builtin_scene("shoebox")
    seg = s.segments()
    assert seg.shape == (4, 2, 2) and seg.dtype == np.float64
    assert s.bounds_m() == (0.0, 0.0, 4.0, 3.0)
    lengths = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
    np.testing.assert_allclose(sorted(lengths), [3, 3, 4, 4])  # a 4 x 3 m rectangle, not square


def test_paper_scene_geometry_from_point_a() -> None:
    scene = builtin_scene("paper")
    assert "RECONSTRUCTION" in scene.description
    seg = scene.segments()
    a = np.array([2.0, 2.0])
    near = [_nearest_on_segment(a, s) for s in seg]
    # Wall 1: 2 m away in +y, foot (2, 4); Wall 2: 2.5 m away in +x, foot (4.5, 2)
    np.testing.assert_allclose(near[0][0], [2.0, 4.0])
    assert near[0][1] == pytest.approx(2.0)
    np.testing.assert_allclose(near[1][0], [4.5, 2.0])
    assert near[1][1] == pytest.approx(2.5)
    # they meet at a right angle in the corner (4.5, 4)
    np.testing.assert_allclose(seg[0][1], [4.5, 4.0])
    np.testing.assert_allclose(seg[1][0], [4.5, 4.0])
    d0, d1 = seg[0][1] - seg[0][0], seg[1][1] - seg[1][0]
    assert d0 @ d1 == pytest.approx(0.0)
    # Wall 3 has no specular point for (a): the perpendicular foot lies off the segment
    foot_x = 2.0
    xs = sorted([seg[2][0][0], seg[2][1][0]])
    assert not xs[0] <= foot_x <= xs[1]
    # everything inside the 5 m x 5 m domain
    xmin, ymin, xmax, ymax = scene.bounds_m()
    assert 0 <= xmin and 0 <= ymin and xmax <= 5 and ymax <= 5


def _reflect(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = (b - a) / np.linalg.norm(b - a)
    q = p - a
    return a + 2 * (q @ d) * d - q


def _cross_param(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Parameters (along p->q, along a->b) of the intersection of the two lines."""
    m = np.array([q - p, a - b]).T
    t, u = np.linalg.solve(m, a - p)
    return float(t), float(u)


def test_paper_wall3_reproduces_the_multibounce_image() -> None:
    """Walls 1 -> 2 -> 3 from (a) heading pi/4 give the Sec. 5 image at (5.5, 1).

    Independent check by image sources: round trip |a - I_123| equals twice the image's
    range, every specular point lies on its finite wall, and the mean Doppler cosine of
    departure and arrival equals the cosine of the image's angle from the heading.
    """
    seg = builtin_scene("paper").segments()
    a = np.array([2.0, 2.0])
    i1 = _reflect(a, *seg[0])
    i2 = _reflect(i1, *seg[1])
    i3 = _reflect(i2, *seg[2])
    image = np.array([5.5, 1.0])
    r_img = np.linalg.norm(image - a)
    assert np.linalg.norm(i3 - a) == pytest.approx(2 * r_img, abs=0.03)
    # back-trace: a -> wall 3 -> wall 2 -> wall 1 -> a, each hit inside its segment
    hits = []
    start, targets = a, [i3, i2, i1]
    for wall, target in zip([2, 1, 0], targets, strict=True):
        t, u = _cross_param(start, target, *seg[wall])
        assert 0 < t < 1 and 0 <= u <= 1
        start = start + t * (target - start)
        hits.append(start)
    np.testing.assert_allclose(hits[0], [2.61, PAPER_WALL3_Y_M], atol=0.01)
    assert hits[0][0] > PAPER_WALL3_X0_M
    heading = np.array([1.0, 1.0]) / math.sqrt(2)
    arr = (hits[0] - a) / np.linalg.norm(hits[0] - a)
    dep = (hits[2] - a) / np.linalg.norm(hits[2] - a)
    cos_img = (image - a) @ heading / r_img
    assert (arr @ heading + dep @ heading) / 2 == pytest.approx(cos_img, abs=0.005)
