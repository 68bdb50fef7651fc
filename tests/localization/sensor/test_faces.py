"""A built map's walls are faces (``WallMap.wall_side``): the echo model predicts no echo that
reaches a wall from a side the mapping runs never heard it from."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from localization.sensor import (
    SensorConfig,
    build_tables,
    explanation,
    predicted_echoes,
    prepare_measurement,
)
from localization.sensor._echo import FACE_TOL_M, faces_only
from localization.sensor._kernels import compact_rows, face_rows
from mapping.forward import WallSet, predicted_heatmap
from mapping.signal import SonarConfig
from mapping.wallmap import WallMap, wallmap_from_walls
from tests.localization.sensor.naive import compact_numpy, faces_numpy

FloatArray = NDArray[np.float64]
ECHO = SensorConfig(model="echo")
SONAR = SonarConfig()
#: A shelf stack's south face (heard from the south aisle, y < 2) and a room's south and
#: north walls. The face runs a = (6, 2) -> b = (2, 2), west, so the south (y < 2) is on
#: its left (side +1); the room's walls run so that the room is on their left too.
FACE = np.array([[6.0, 2.0, 2.0, 2.0]])
ROOM = np.array([[0.0, 0.0, 8.0, 0.0], [8.0, 5.0, 0.0, 5.0]])


def _sided(walls: FloatArray, side: list[int]) -> WallMap:
    wm = wallmap_from_walls(walls)
    return dataclasses.replace(wm, provenance={"fit": {"heard_side": side}})


def test_wall_side_reads_the_fit_and_defaults_to_two_sided() -> None:
    walls = np.vstack([FACE, ROOM])
    assert _sided(walls, [1, -1, 0]).wall_side.tolist() == [1, -1, 0]
    assert wallmap_from_walls(walls).wall_side.tolist() == [0, 0, 0]     # geometry: both
    for bad in ([1, 2, 0], [1, -1], "x"):                                 # not a side list
        assert _sided(walls, bad).wall_side.tolist() == [0, 0, 0]        # type: ignore[arg-type]
    assert build_tables(wallmap_from_walls(walls), ECHO).wall_side is None


def test_a_face_is_heard_from_its_side_only() -> None:
    """The stack's face at y = 2 (a -> b points west, so the south is its left, side +1):
    from the south aisle (y = 1.2) the model predicts its echo at 0.8 m as before; from the
    middle aisle (y = 2.85, behind the face) it predicts none, where a two-sided wall
    predicts one at 0.85 m (the echo of the stack's unmapped north face that a filter would
    explain with it)."""
    walls = np.vstack([FACE, ROOM])
    one = build_tables(_sided(walls, [1, 1, 1]), ECHO)
    two = build_tables(wallmap_from_walls(walls), ECHO)
    south = np.array([[4.0, 1.2, 0.0]])
    behind = np.array([[4.0, 2.85, 0.0]])

    def first_order_ranges(tables, pose):  # type: ignore[no-untyped-def]
        b, _ = predicted_echoes(tables, 0.1, pose, parallel=False)
        k = int(b.count[0])
        return sorted(np.round(b.range_m[0, :k][b.order[0, :k] == 1], 3).tolist())

    assert first_order_ranges(one, south) == first_order_ranges(two, south)
    assert 0.8 in first_order_ranges(one, south)
    assert 0.85 in first_order_ranges(two, behind)
    assert 0.85 not in first_order_ranges(one, behind)
    # the room's north wall was heard from inside: still heard from behind the stack (the
    # south wall is hidden by the stack either way: a face still blocks sound from behind)
    assert 2.15 in first_order_ranges(one, behind)
    assert 2.85 not in first_order_ranges(two, behind)


def test_a_peak_behind_a_face_is_not_explained_by_it() -> None:
    """A block heard at the true pose in the middle aisle of the real stack room (the stack
    4 x 0.4 m: faces at y = 2.0 and 2.4): on the map of the south face only, the pose 40 cm
    south of the truth, where the south face takes the place of the north one, explains
    the block better than the truth when the face is two-sided, and no better when it is
    one-sided."""
    stack = np.array([[2.0, 2.0, 6.0, 2.0], [6.0, 2.0, 6.0, 2.4], [6.0, 2.4, 2.0, 2.4],
                      [2.0, 2.4, 2.0, 2.0]])
    truth = np.array([4.0, 3.25, math.pi])
    hm = predicted_heatmap(WallSet.from_array(np.vstack([stack, ROOM])), truth, 0.12, SONAR)
    meas = prepare_measurement(hm, ECHO)
    walls = np.vstack([FACE, ROOM])
    poses = np.array([truth, truth - [0.0, 0.40, 0.0]])
    ll_two = explanation(build_tables(wallmap_from_walls(walls), ECHO), meas, poses)
    ll_one = explanation(build_tables(_sided(walls, [1, 1, 1]), ECHO), meas, poses)
    assert ll_two.log_likelihood[1] > ll_two.log_likelihood[0]
    assert ll_one.log_likelihood[1] <= ll_one.log_likelihood[0]


def test_faces_only_keeps_range_order_and_padding() -> None:
    """Dropped echoes leave the row; the rest keep their order and the padding its fill."""
    walls = np.vstack([FACE, ROOM])
    tables = build_tables(_sided(walls, [1, 1, 1]), ECHO)
    rng = np.random.default_rng(3)
    poses = np.column_stack([rng.uniform(0.5, 7.5, 50), rng.uniform(0.3, 4.7, 50),
                             rng.uniform(-math.pi, math.pi, 50)])
    full, _ = predicted_echoes(build_tables(wallmap_from_walls(walls), ECHO), 0.1, poses,
                               parallel=False)
    kept = faces_only(tables, full, poses)
    assert np.all(kept.count <= full.count) and np.any(kept.count < full.count)
    for i in range(poses.shape[0]):
        k = int(kept.count[i])
        r = kept.range_m[i, :k]
        assert np.all(np.diff(r) >= 0)
        assert set(np.round(r, 9)) <= set(np.round(full.range_m[i, :full.count[i]], 9))
        assert np.all(np.isnan(kept.range_m[i, k:])) and np.all(kept.walls[i, k:] == -1)
        behind = poses[i, 1] > 2.0 + FACE_TOL_M and 2.0 <= poses[i, 0] <= 6.0
        if behind:   # no echo of the face's first bounce from behind it
            first = kept.walls[i, :k, 0]
            assert not np.any(first == 0)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 30), st.integers(1, 7), st.integers(1, 3),
       st.integers(0, 2**32 - 1))
def test_face_kernel_matches_its_numpy_twin(n_walls: int, n: int, k: int, order: int,
                                            seed: int) -> None:
    """Random walls and sides, poses on both sides, bounce lists padded with -1 / NaN:
    the numba kernel and its parallel twin against the plain loop."""
    rng = np.random.default_rng(seed)
    seg = rng.uniform(-3, 3, (n_walls, 2, 2))
    seg[:, 1] += rng.uniform(0.2, 1.0, (n_walls, 2))
    side = rng.integers(-1, 2, n_walls).astype(np.int64)
    poses = np.column_stack([rng.uniform(-4, 4, (n, 2)), rng.uniform(-3, 3, n)])
    count = rng.integers(0, k + 1, n).astype(np.int64)
    idx = rng.integers(-1, n_walls, (n, k, order)).astype(np.int64)
    t = rng.uniform(-0.3, 1.3, (n, k, order))
    w = np.maximum(idx, 0)
    pts = seg[w, 0] + t[..., None] * (seg[w, 1] - seg[w, 0]) + rng.normal(0, 0.03, (n, k, order, 2))
    pts[idx < 0] = np.nan
    want = faces_numpy(seg, side, poses, count, idx, pts, FACE_TOL_M)
    np.testing.assert_array_equal(face_rows(seg, side, poses, count, idx, pts, FACE_TOL_M), want)
    np.testing.assert_array_equal(
        face_rows(seg, side, poses, count, idx, pts, FACE_TOL_M, parallel=True), want)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 30), st.integers(1, 7), st.integers(1, 3), st.integers(0, 2**32 - 1))
def test_compaction_kernel_matches_its_numpy_twin(n: int, k: int, order: int,
                                                  seed: int) -> None:
    """Random keep masks over random fields (NaNs included): the numba compaction and its
    parallel twin against the plain loop, padding and all."""
    rng = np.random.default_rng(seed)
    keep = rng.random((n, k)) < 0.6
    f = rng.normal(size=(4, n, k))
    f[rng.random(f.shape) < 0.1] = np.nan
    orders = rng.integers(0, 4, (n, k)).astype(np.int64)
    walls = rng.integers(-1, 9, (n, k, order)).astype(np.int64)
    points = rng.normal(size=(n, k, order, 2))
    want = compact_numpy(keep, f, orders, walls, points)
    for parallel in (False, True):
        got = compact_rows(keep, f, orders, walls, points, parallel)
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(a, b)


def test_faces_only_keeps_the_batch_when_nothing_is_dropped_and_compacts_otherwise() -> None:
    """From the south aisle every echo is from a heard side: the batch comes back as it
    was; from the middle aisle the kept rows equal the full batch's rows without the
    dropped echoes (fields checked one by one against the mask)."""
    walls = np.vstack([FACE, ROOM])
    tables = build_tables(_sided(walls, [1, 1, 1]), ECHO)
    south = np.array([[3.0, 1.2, 0.3], [4.5, 1.0, -2.0]])
    full, _ = predicted_echoes(build_tables(wallmap_from_walls(walls), ECHO), 0.1, south,
                               parallel=False)
    assert faces_only(tables, full, south) is full
    mid = np.array([[3.0, 2.85, 0.3], [4.0, 3.5, 1.0], [1.0, 1.0, 0.0]])
    full, _ = predicted_echoes(build_tables(wallmap_from_walls(walls), ECHO), 0.1, mid,
                               parallel=False)
    seg = np.asarray(tables.soft_ends[0].segments_m, dtype=np.float64).reshape(-1, 2, 2)
    assert tables.wall_side is not None
    keep = face_rows(seg, tables.wall_side, mid, full.count, full.walls, full.points_m,
                     FACE_TOL_M)
    kept = faces_only(tables, full, mid)
    assert kept.count.tolist() == keep.sum(axis=1).tolist()
    assert np.any(kept.count < full.count)
    for i in range(mid.shape[0]):
        sel = np.flatnonzero(keep[i])
        k = sel.size
        for name in ("range_m", "cos_doppler", "amplitude", "arrival_bearing_rad", "order",
                     "walls", "points_m"):
            np.testing.assert_array_equal(getattr(kept, name)[i, :k],
                                          getattr(full, name)[i, sel], err_msg=name)
