"""Image-source geometry: hand-derived images, counts, validity on finite segments, occlusion."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.simulate.ism import candidate_images, mirror_maps, trace_images

LX, LY = 5.0, 4.0
SHOEBOX = np.array(
    [[[0, 0], [LX, 0]], [[LX, 0], [LX, LY]], [[LX, LY], [0, LY]], [[0, LY], [0, 0]]], float
)
# L-shaped room (re-entrant corner at (3, 3)): lower arm [0,6]x[0,3], upper arm [0,3]x[0,6]
L_CORNERS = [(0, 0), (6, 0), (6, 3), (3, 3), (3, 6), (0, 6)]
L_ROOM = np.array([[L_CORNERS[i], L_CORNERS[(i + 1) % 6]] for i in range(6)], float)
# 6 m square room with a 1 m square pillar [2, 3] x [2, 3]
PILLAR_ROOM = np.concatenate(
    [
        np.array([[[0, 0], [6, 0]], [[6, 0], [6, 6]], [[6, 6], [0, 6]], [[0, 6], [0, 0]]], float),
        np.array([[[2, 2], [3, 2]], [[3, 2], [3, 3]], [[3, 3], [2, 3]], [[2, 3], [2, 2]]], float),
    ]
)


def _trace(segments: np.ndarray, xy: tuple[float, float], order: int):
    pos = np.array([xy], float)
    images = candidate_images(segments, pos, order)
    return images, trace_images(images, segments, np.ones(len(segments)), pos)


def _valid_points(segments: np.ndarray, xy: tuple[float, float], order: int) -> dict:
    images, tr = _trace(segments, xy, order)
    pts = images.positions(np.array([xy], float))[:, 0]
    out = {}
    for i in np.flatnonzero(tr.valid[:, 0]):
        walls = tuple(int(w) for w in tr.walls[i, 0] if w >= 0)
        out[tuple(np.round(pts[i], 9))] = (int(tr.order[i, 0]), walls)
    return out


def test_shoebox_images_up_to_order_two_by_hand():
    x, y = 1.0, 1.5
    got = _valid_points(SHOEBOX, (x, y), 2)
    first = {(x, -y), (2 * LX - x, y), (x, 2 * LY - y), (-x, y)}
    corners = {(2 * LX - x, -y), (-x, -y), (2 * LX - x, 2 * LY - y), (-x, 2 * LY - y)}
    parallel = {(x, 2 * LY + y), (x, -2 * LY + y), (2 * LX + x, y), (-2 * LX + x, y)}
    assert {p for p, (k, _) in got.items() if k == 1} == first
    assert {p for p, (k, _) in got.items() if k == 2} == corners | parallel
    # the walls of the traced paths, in the order the sound hits them: bottom (0) then
    # top (2) gives y -> -y -> 2 LY + y
    assert got[(x, 2 * LY + y)][1] == (0, 2)
    assert got[(x, -2 * LY + y)][1] == (2, 0)


@settings(max_examples=25, deadline=None)
@given(st.floats(0.1, LX - 0.1), st.floats(0.1, LY - 0.1))
def test_shoebox_has_4k_images_of_order_k(x, y):
    images, tr = _trace(SHOEBOX, (x, y), 4)
    counts = np.bincount(tr.order[tr.valid[:, 0], 0], minlength=5)
    assert counts[1:].tolist() == [4, 8, 12, 16]
    # a shoebox image is valid everywhere inside: the lattice (+-x + 2 m LX, +-y + 2 n LY)
    pts = images.positions(np.array([[x, y]]))[tr.valid[:, 0], 0]
    for px, py in pts:
        mx = min(abs(px - x - 2 * LX * round((px - x) / (2 * LX))),
                 abs(px + x - 2 * LX * round((px + x) / (2 * LX))))
        my = min(abs(py - y - 2 * LY * round((py - y) / (2 * LY))),
                 abs(py + y - 2 * LY * round((py + y) / (2 * LY))))
        assert mx < 1e-9 and my < 1e-9


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-5, 5), min_size=4, max_size=4), st.floats(-5, 5), st.floats(-5, 5))
def test_mirror_maps_are_involutions_fixing_the_wall(coords, px, py):
    seg = np.array([[coords[:2], coords[2:]]], float)
    if np.linalg.norm(seg[0, 1] - seg[0, 0]) < 1e-3:
        return
    A, b = mirror_maps(seg)
    p = np.array([px, py])
    twice = A[0] @ (A[0] @ p + b[0]) + b[0]
    assert np.allclose(twice, p, atol=1e-9)
    mid = seg[0].mean(axis=0)
    assert np.allclose(A[0] @ mid + b[0], mid, atol=1e-9)  # points on the wall stay put
    assert np.isclose(np.linalg.det(A[0]), -1.0)


def test_finite_wall_gives_no_echo_past_its_end():
    wall = np.array([[[0.0, 2.0], [2.0, 2.0]]])
    for x, expected in [(1.0, True), (1.999, True), (2.001, False), (3.0, False), (-0.5, False)]:
        _, tr = _trace(wall, (x, 0.0), 1)
        assert bool(tr.valid[0, 0]) is expected, x


def test_l_room_hidden_walls_give_no_first_order_echo():
    # from (5, 1) in the lower arm: the inner wall x = 3 (y 3..6, index 3) and the far wall
    # y = 6 (x 0..3, index 4) are out of sight; floor, right, step and left walls are seen
    got = _valid_points(L_ROOM, (5.0, 1.0), 1)
    seen = {walls[0] for k, walls in got.values() if k == 1}
    assert seen == {0, 1, 2, 5}
    # from (1, 5) in the upper arm the right wall (x = 6, y 0..3) and step wall are hidden
    got = _valid_points(L_ROOM, (1.0, 5.0), 1)
    assert {walls[0] for k, walls in got.values() if k == 1} == {0, 3, 4, 5}


def test_pillar_occludes_the_wall_behind_it():
    # (2.5, 1) below the pillar: the top wall y = 6 is hidden (its path would cross the
    # pillar); the pillar's bottom face answers instead
    got = _valid_points(PILLAR_ROOM, (2.5, 1.0), 1)
    seen = {walls[0] for k, walls in got.values() if k == 1}
    assert 2 not in seen and 4 in seen
    assert seen == {0, 1, 3, 4}
    # beside the pillar the top wall is seen
    got = _valid_points(PILLAR_ROOM, (4.5, 1.0), 1)
    assert 2 in {walls[0] for k, walls in got.values() if k == 1}


# ---- wall order: the order the sound hits them (regression) -------------------------------
# wall A along the x axis, wall B at 60 degrees; both start at the apex (0, 0)
WEDGE = np.array([[[0.0, 0.0], [4.0, 0.0]], [[0.0, 0.0], [2.0, 2.0 * math.sqrt(3.0)]]])


def _rotation(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def _reflect(d: np.ndarray, wall: np.ndarray) -> np.ndarray:
    """Direction ``d`` after a specular reflection in ``wall``'s line."""
    t = (wall[1] - wall[0]) / np.linalg.norm(wall[1] - wall[0])
    return 2.0 * np.dot(d, t) * t - d


def _ray_hit(p: np.ndarray, d: np.ndarray, wall: np.ndarray) -> tuple[float, float]:
    """Ray parameter s > 0 and wall parameter u where ``p + s d`` meets ``wall``."""
    e = wall[1] - wall[0]
    s, u = np.linalg.solve(np.column_stack([d, -e]), wall[0] - p)
    return float(s), float(u)


def test_traced_walls_are_in_the_order_the_sound_hits_them():
    """Two walls at 60 degrees, robot at x = (1.5, 0.5) between them. By hand: the sound that
    hits A first and then B comes back from the image M_B(M_A x), the rotation of x by +120
    degrees about the apex, (-1.1830, 1.0490); its first reflection point is where the line
    from x to M_A(M_B x) = R(-120) x = (-0.3170, -1.5490) crosses A, (1.0566, 0). The reverse
    path (B first) comes from R(-120) x. A ray followed by the law of reflection (no images)
    from x through (1.0566, 0) goes on to B and back to x. Regression: the trace used to list
    the walls receiver-first, i.e. (B, A) for this path."""
    x = np.array([1.5, 0.5])
    images, tr = _trace(WEDGE, tuple(x), 2)
    pts = images.positions(x[None])[:, 0]
    second = {tuple(int(w) for w in tr.walls[i, 0] if w >= 0): pts[i]
              for i in np.flatnonzero(tr.valid[:, 0] & (tr.order[:, 0] == 2))}
    assert set(second) == {(0, 1), (1, 0)}
    assert np.allclose(second[(0, 1)], [-1.1830127, 1.0490381], atol=1e-6)
    assert np.allclose(second[(0, 1)], _rotation(120.0) @ x, atol=1e-12)
    assert np.allclose(second[(1, 0)], _rotation(-120.0) @ x, atol=1e-12)
    # first reflection point of the (A, B) path, by unfolding: on A, at (1.0566, 0)
    far = _rotation(-120.0) @ x
    p_a = x + (x[1] / (x[1] - far[1])) * (far - x)
    assert abs(p_a[1]) < 1e-12 and abs(p_a[0] - 1.0566243) < 1e-6
    # the law of reflection from there: A, then B, then straight back to x
    d = _reflect(p_a - x, WEDGE[0])
    s, u = _ray_hit(p_a, d, WEDGE[1])
    assert s > 0 and 0 <= u <= 1
    p_b = p_a + s * d
    d = _reflect(d, WEDGE[1])
    back = x - p_b
    assert abs(d[0] * back[1] - d[1] * back[0]) < 1e-9 and np.dot(d, back) > 0
    length = np.linalg.norm(p_a - x) + np.linalg.norm(p_b - p_a) + np.linalg.norm(x - p_b)
    assert abs(length - np.linalg.norm(second[(0, 1)] - x)) < 1e-9


# ---- a second, independent method: solve the reflection points directly -----------------
def _brute_valid(segments: np.ndarray, x: np.ndarray, walls: tuple[int, ...]) -> bool:
    """Validity by constructing the image chain and back-tracking the reflection points."""
    A, b = mirror_maps(segments)
    imgs = [x]
    for w in walls:
        imgs.append(A[w] @ imgs[-1] + b[w])
    if np.linalg.norm(imgs[-1] - x) < 1e-9:
        return False
    points: list[np.ndarray] = []
    target = x  # receiver
    for k in range(len(walls) - 1, -1, -1):
        w = walls[k]
        c0, d = segments[w, 0], segments[w, 1] - segments[w, 0]
        r = imgs[k + 1] - target
        den = r[0] * d[1] - r[1] * d[0]
        if abs(den) < 1e-15:
            return False
        q = c0 - target
        s = (q[0] * d[1] - q[1] * d[0]) / den
        u = (q[0] * r[1] - q[1] * r[0]) / den
        s_min = 1e-9 if k == len(walls) - 1 else -1e-9  # a corner bounce has s = 0
        if not (s_min < s < 1 - 1e-12 and -1e-9 <= u <= 1 + 1e-9):
            return False
        if abs(s) <= 1e-9:  # two bounces at one point: only an inside corner reflects
            came_from = points[-2] if len(points) >= 2 else x
            if not _inside_corner(segments[walls[k + 1]], segments[w], target, came_from):
                return False
        target = target + s * r
        points.append(target)
    legs = list(itertools.pairwise([x, *points, x]))
    for p, q in legs:
        for w in range(len(segments)):
            if _crosses(p, q, segments[w]):
                return False
    return True


def _inside_corner(wall_a: np.ndarray, wall_b: np.ndarray, corner: np.ndarray,
                   x: np.ndarray) -> bool:
    """Each wall runs from the corner into the other's half-plane on the side of x (the
    air side of both: an inside corner); at an outside corner one of them runs away."""
    def side(seg: np.ndarray, p: np.ndarray) -> float:
        d = seg[1] - seg[0]
        return float(d[0] * (p[1] - seg[0][1]) - d[1] * (p[0] - seg[0][0]))

    def reaches(seg: np.ndarray, other: np.ndarray) -> bool:
        return any(side(other, end) * side(other, x) > 1e-12 for end in seg
                   if np.hypot(*(end - corner)) > 1e-9)

    return reaches(wall_a, wall_b) and reaches(wall_b, wall_a)


def _crosses(p: np.ndarray, q: np.ndarray, seg: np.ndarray) -> bool:
    """Proper crossing of segment p-q with a wall, away from the leg's end points."""
    r, d = q - p, seg[1] - seg[0]
    den = r[0] * d[1] - r[1] * d[0]
    if abs(den) < 1e-15:
        return False
    w = seg[0] - p
    s = (w[0] * d[1] - w[1] * d[0]) / den
    u = (w[0] * r[1] - w[1] * r[0]) / den
    return bool(1e-7 < s < 1 - 1e-7 and -1e-9 <= u <= 1 + 1e-9)


@pytest.mark.parametrize("segments", [L_ROOM, PILLAR_ROOM, SHOEBOX], ids=["l", "pillar", "box"])
@settings(max_examples=30, deadline=None)
@given(st.floats(0.05, 0.95), st.floats(0.05, 0.95))
def test_trace_agrees_with_direct_reflection_points_up_to_order_two(segments, fx, fy):
    lo, hi = segments.reshape(-1, 2).min(axis=0), segments.reshape(-1, 2).max(axis=0)
    x = lo + np.array([fx, fy]) * (hi - lo)
    inside_l = not (x[0] > 2.95 and x[1] > 2.95)
    inside_pillar = not (1.95 < x[0] < 3.05 and 1.95 < x[1] < 3.05)
    if (segments is L_ROOM and not inside_l) or (segments is PILLAR_ROOM and not inside_pillar):
        return
    got = _valid_points(segments, tuple(x), 2)
    W = len(segments)
    expected = set()
    for k in (1, 2):
        for walls in itertools.product(range(W), repeat=k):
            if any(a == b for a, b in itertools.pairwise(walls)):
                continue
            if _brute_valid(segments, x, walls):
                A, b = mirror_maps(segments)
                p = x
                for w in walls:
                    p = A[w] @ p + b[w]
                expected.add(tuple(np.round(p, 9)))
    assert set(got) == expected


def test_candidate_pruning_by_distance_keeps_every_path_in_range():
    pos = np.array([[1.0, 1.5]])
    limit = 30.0
    images = candidate_images(SHOEBOX, pos, 20, max_path_m=limit)
    tr = trace_images(images, SHOEBOX, np.ones(4), pos)
    n_in = int(np.sum(tr.valid[:, 0] & (tr.path_length_m[:, 0] <= limit)))
    # the shoebox image lattice, counted directly
    expected = 0
    for m in range(-10, 11):
        for n in range(-10, 11):
            for sx, sy in itertools.product((1, -1), repeat=2):
                p = np.array([sx * 1.0 + 2 * m * LX, sy * 1.5 + 2 * n * LY])
                dist = np.linalg.norm(p - pos[0])
                if 1e-9 < dist <= limit:
                    expected += 1
    assert n_in == expected
    assert images.max_order < 20


def test_bad_segments_raise():
    with pytest.raises(ValueError, match="segments"):
        candidate_images(np.zeros((1, 2, 2)), np.zeros((1, 2)), 1)
    with pytest.raises(ValueError, match="max_order"):
        candidate_images(SHOEBOX, np.zeros((1, 2)), 0)
    with pytest.raises(ValueError, match="reflection"):
        images = candidate_images(SHOEBOX, np.ones((1, 2)), 1)
        trace_images(images, SHOEBOX, np.ones(3), np.ones((1, 2)))


def test_image_cap_truncates_whole_orders_or_raises():
    pos = np.array([[1.0, 1.5]])
    full = candidate_images(SHOEBOX, pos, 6)
    capped = candidate_images(SHOEBOX, pos, 6, max_images=30, truncate=True)
    assert capped.truncated and not full.truncated
    assert capped.n <= 30 and capped.max_order < 6
    # every order kept is complete: the same images as the uncapped set up to that order
    keep = full.order <= capped.max_order
    assert capped.n == int(np.sum(keep))
    with pytest.raises(ValueError, match="max_images"):
        candidate_images(SHOEBOX, pos, 6, max_images=30)


def test_outside_corner_gives_no_two_bounce_path():
    # two walls meeting at an outside (reflex) corner: from the air side at 270 deg there is
    # no specular two-bounce path (issue 15); the paths left are the first-order ones
    walls = np.array([[[0, 0], [4, 0]], [[0, 0], [0, 4]]], float)  # the solid is x, y > 0
    for xy in [(-1.0, -1.0), (-2.0, -0.5), (-0.5, -3.0)]:
        got = _valid_points(walls, xy, 2)
        assert all(k == 1 for k, _ in got.values()), (xy, got)


def test_inside_corner_keeps_its_one_two_bounce_image():
    walls = np.array([[[0, 0], [4, 0]], [[0, 0], [0, 4]]], float)  # the air is x, y > 0
    got = _valid_points(walls, (1.0, 2.0), 2)
    assert sorted(k for k, _ in got.values()) == [1, 1, 2]
    assert (-1.0, -2.0) in got


def test_l_room_re_entrant_corner_gives_no_phantom_echo():
    # from the lower arm, the reflex corner (3, 3) of the L used to give a full-strength
    # "two bounces at one point" echo; geometric acoustics gives none
    for xy in [(5.0, 1.0), (4.2, 0.6), (1.0, 5.0)]:
        got = _valid_points(L_ROOM, xy, 2)
        for k, walls in got.values():
            assert not (k == 2 and set(walls) == {2, 3}), (xy, walls)


@pytest.mark.parametrize(("name", "xy"), [("l-room", (3.0, 0.7)), ("pillar", (0.6, 2.1))])
def test_coincident_image_maps_trace_one_path(name, xy):
    # regression (issue 15): two distinct maps sending the robot to the same point (built-in
    # L-room on x = 3, pillar room on x = 0.6) both traced the one physical path: heard twice
    from mapping.scene import builtin_scene

    seg = builtin_scene(name).segments()
    images, tr = _trace(seg, xy, 3)
    pts = images.positions(np.array([xy], float))[tr.valid[:, 0], 0]
    assert len(pts) == len(np.unique(np.round(pts, 7), axis=0))
    # the duplicate was a second map of the same point, not a missing path: off the line the
    # path count is unchanged
    _, near = _trace(seg, (xy[0] + 1e-4, xy[1]), 3)
    assert int(tr.valid.sum()) == int(near.valid.sum())
