"""Floor and ceiling copies of the forward model's echoes (``mapping.forward._vertical``)
against the 3-D image source written out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mapping.forward import ForwardParams, WallSet, echoes_batch, vertical_images, with_vertical
from mapping.signal import SonarConfig

CFG = SonarConfig()


def test_vertical_images_by_hand() -> None:
    """Sonar 0.3 m up, ceiling 2.6 m, two bounces: floor 2h = 0.6 (0.9), ceiling
    2(H - h) = 4.6 (0.7), floor-ceiling and ceiling-floor 2H = 5.2 (2 x 0.9 x 0.7)."""
    dz, refl = vertical_images(0.3, 2.6, 0.9, 0.7, 2)
    np.testing.assert_allclose(dz, [0.6, 4.6, 5.2])
    np.testing.assert_allclose(refl, [0.9, 0.7, 2 * 0.63])
    dz, refl = vertical_images(0.3, None, 0.9, 0.7, 2)  # a floor alone
    np.testing.assert_allclose(dz, [0.6]) and np.testing.assert_allclose(refl, [0.9])
    assert vertical_images(None, None, 0.9, 0.7, 2)[0].size == 0


@pytest.mark.parametrize(("h", "top", "rf", "rc", "n", "word"), [
    (-0.1, None, 0.9, 0.7, 2, "sonar_height_m"), (0.3, 0.2, 0.9, 0.7, 2, "ceiling_height_m"),
    (None, 2.0, 0.9, 0.7, 2, "ceiling_height_m"), (0.3, 2.6, 1.5, 0.7, 2, "floor_reflection"),
    (0.3, 2.6, 0.9, 0.7, 0, "bounces")])
def test_bad_vertical_geometry_is_named(h: float | None, top: float | None, rf: float,
                                        rc: float, n: int, word: str) -> None:
    with pytest.raises(ValueError, match=word):
        vertical_images(h, top, rf, rc, n)


def test_copies_are_the_3d_image_sources() -> None:
    """One wall x = 2 m (strength 0.8), sonar at the origin 0.3 m up moving at 0.2 m/s at
    30 deg: the floor copy of the wall echo is the image of the sonar mirrored in the wall
    and the floor, (4, 0, -0.3): one-way range |(4, 0, -0.6)| / 2 and Doppler cosine the 2-D
    one times L2 / L3 (the motion is horizontal: dL3/dt = (L2 / L3) dL2/dt); amplitude
    0.8 x 0.9 / L3 (3-D spreading)."""
    walls = WallSet(segments_m=np.array([[[2.0, -20.0], [2.0, 20.0]]]),
                    strength=np.array([0.8]))
    pose = np.array([[0.0, 0.0, math.radians(30)]])
    b = echoes_batch(walls, pose, 0.0, CFG, ForwardParams(max_order=1))  # no retardation
    assert int(b.count[0]) == 1
    dz, refl = vertical_images(0.3, None, 0.9, 0.7, 1)
    v = with_vertical(b, dz, refl)
    assert int(v.count[0]) == 2
    l2, l3 = 4.0, math.hypot(4.0, 0.6)
    assert v.range_m[0, 1] == pytest.approx(l3 / 2, abs=1e-12)
    assert v.cos_doppler[0, 1] == pytest.approx(math.cos(math.radians(30)) * l2 / l3, abs=1e-12)
    assert v.amplitude[0, 1] == pytest.approx(0.8 * 0.9 / l3, rel=1e-12)
    assert v.range_m[0, 0] == b.range_m[0, 0] and v.walls[0, 1, 0] == 0


def test_rows_keep_each_echo_then_its_copies() -> None:
    """Two poses with different counts: row i holds count[i] * (1 + V) entries, the first of
    each group the original echo; no copy without an echo."""
    walls = WallSet(segments_m=np.array([[[2.0, -20.0], [2.0, 20.0]], [[-1.0, 3.0], [1.0, 3.0]]]),
                    strength=np.array([1.0, 1.0]))
    poses = np.array([[0.0, 0.0, 0.0], [0.0, 5.0, 0.0]])  # the second sees the segment's back
    b = echoes_batch(walls, poses, 0.1, CFG, ForwardParams(max_order=1))
    dz, refl = vertical_images(0.3, 2.6, 0.9, 0.7, 2)
    v = with_vertical(b, dz, refl)
    copies = 1 + dz.size
    np.testing.assert_array_equal(v.count, b.count * copies)
    for i in range(2):
        for k in range(int(b.count[i])):
            assert v.range_m[i, k * copies] == b.range_m[i, k]
            assert np.all(v.range_m[i, k * copies + 1:(k + 1) * copies] > b.range_m[i, k])
