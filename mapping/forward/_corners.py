"""Inside corners of a fitted map as the sonar hears them: one retro-reflection at the vertex.

A monostatic sonar inside a right-angle corner hears one two-bounce echo that travels to the
vertex and back (the corner is a retro-reflector: the image of the sonar in both walls is its
point reflection through the vertex, so the path passes through it). A *fitted* corner is
never exactly 90 deg: its exact image paths then miss the vertex by a fraction of a
millimetre and either vanish (the specular points fall off the segments) or split in two
((i, j) and (j, i) no longer share one image map). Both are artefacts of the fit, not of the
room. For corners within a tolerance of 90 deg whose walls share an end (:func:`right_corners`),
the kernel (``_kernels._pose_echoes``) replaces every exact order-2 path of the pair by the
vertex echo the room gives; this module finds the corners and says where a vertex is heard
(:func:`vertex_paths`). The numpy twin of the replacement is ``regularize_corners`` in
``tests/mapping/forward/naive.py``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    return np.asarray(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])


def shared_vertices(segments_m: FloatArray, join_m: float = 0.05
                    ) -> list[tuple[int, int, FloatArray]]:
    """Pairs of walls (segments (W, 2, 2)) with an end each within ``join_m`` of the other:
    ``(i, j, vertex)`` with i < j and the vertex the midpoint of the two ends (ordered by
    i, j, then the ends of i and of j)."""
    seg = np.asarray(segments_m, dtype=np.float64).reshape(-1, 2, 2)
    gap = seg[:, None, :, None, :] - seg[None, :, None, :, :]  # [i, j, end of i, end of j]
    near = np.hypot(gap[..., 0], gap[..., 1]) <= join_m
    near &= np.triu(np.ones((seg.shape[0],) * 2, dtype=bool), k=1)[:, :, None, None]
    return [(int(i), int(j), 0.5 * (seg[i, ei] + seg[j, ej]))
            for i, j, ei, ej in zip(*np.nonzero(near), strict=True)]


def _far_end(seg: FloatArray, vertex: FloatArray) -> FloatArray:
    d0, d1 = math.hypot(*(seg[0] - vertex)), math.hypot(*(seg[1] - vertex))
    return np.asarray(seg[1] if d0 < d1 else seg[0])


def corner_angle_deg(segments_m: FloatArray, i: int, j: int, vertex: FloatArray) -> float:
    """Angle between walls i and j at their shared ``vertex`` (0-180 deg)."""
    _, _, ea, eb = _corner_arrays(segments_m, [(i, j, np.asarray(vertex, dtype=np.float64))])
    return float(_angles_deg(ea, eb)[0])


def _angles_deg(ea: FloatArray, eb: FloatArray) -> FloatArray:
    """Angle between each pair of edges (m, 2), (m, 2) in degrees (0-180)."""
    norms = np.sqrt(np.sum(ea * ea, axis=1)) * np.sqrt(np.sum(eb * eb, axis=1))
    cos = np.sum(ea * eb, axis=1) / np.maximum(norms, 1e-300)
    return np.asarray(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def right_corners(segments_m: FloatArray, tol_deg: float, join_m: float = 0.05
                  ) -> list[tuple[int, int, FloatArray]]:
    """Shared vertices (:func:`shared_vertices`) whose angle (:func:`corner_angle_deg`) is
    within ``tol_deg`` of 90."""
    shared = shared_vertices(segments_m, join_m)
    angle = _angles_deg(*_corner_arrays(segments_m, shared)[2:])
    return [c for c, a in zip(shared, angle, strict=True) if abs(a - 90.0) <= tol_deg]


def _blocked_to(p: FloatArray, vertex: FloatArray, seg: FloatArray,
                exclude: tuple[int, int]) -> NDArray[np.bool_]:
    """Whether a wall other than ``exclude`` crosses the leg from each p (n, 2) to the vertex."""
    out = np.zeros(p.shape[0], dtype=bool)
    r = vertex - p
    for w in range(seg.shape[0]):
        if w in exclude:
            continue
        a, d = seg[w, 0], seg[w, 1] - seg[w, 0]
        den = _cross(r, np.broadcast_to(d, r.shape))
        q = a - p
        with np.errstate(divide="ignore", invalid="ignore"):
            s = _cross(q, np.broadcast_to(d, r.shape)) / den
            u = _cross(q, r) / den
        out |= (np.abs(den) > 1e-15) & (s > 1e-9) & (s < 1 - 1e-9) & (u >= 0) & (u <= 1)
    return out


def vertex_paths(segments_m: FloatArray, poses: FloatArray,
                 corners: list[tuple[int, int, FloatArray]]
                 ) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Distance from each pose (n, 3) to each corner's vertex (n, m), and whether the vertex
    echo is heard: the pose lies strictly inside the convex wedge of the two walls and no
    other wall crosses the line of sight."""
    seg = np.asarray(segments_m, dtype=np.float64)
    p = np.asarray(poses, dtype=np.float64)[:, :2]
    n = p.shape[0]
    dist = np.full((n, len(corners)), np.nan)
    ok = np.zeros((n, len(corners)), dtype=bool)
    for m, (i, j, vertex) in enumerate(corners):
        ea = _far_end(seg[i], vertex) - vertex
        eb = _far_end(seg[j], vertex) - vertex
        k = float(_cross(ea, eb))
        q = p - vertex
        dist[:, m] = np.hypot(q[:, 0], q[:, 1])
        if abs(k) < 1e-9:
            continue
        inside = ((_cross(np.broadcast_to(ea, q.shape), q) * k > 0)
                  & (_cross(q, np.broadcast_to(eb, q.shape)) * k > 0))
        ok[:, m] = inside & ~_blocked_to(p, vertex, seg, exclude=(i, j))
    return dist, ok


def _corner_arrays(segments_m: FloatArray, corners: list[tuple[int, int, FloatArray]]
                   ) -> tuple[IntArray, FloatArray, FloatArray, FloatArray]:
    """The corners as the kernel takes them: wall pairs (m, 2), vertices (m, 2) and the
    wedge edges ``ea``, ``eb`` (m, 2) from the vertex to the far end of each wall."""
    seg = np.asarray(segments_m, dtype=np.float64).reshape(-1, 2, 2)
    pairs = np.array([c[:2] for c in corners], dtype=np.int64).reshape(-1, 2)
    vertex = np.array([c[2] for c in corners], dtype=np.float64).reshape(-1, 2)
    return pairs, vertex, _edges(seg, pairs[:, 0], vertex), _edges(seg, pairs[:, 1], vertex)


def _edges(seg: FloatArray, walls: IntArray, vertex: FloatArray) -> FloatArray:
    """From each vertex (m, 2) to the far end (:func:`_far_end`) of its wall (m,)."""
    ends = seg[walls] - vertex[:, None, :]
    dist = np.hypot(ends[..., 0], ends[..., 1])
    return np.where((dist[:, 0] < dist[:, 1])[:, None], ends[:, 1], ends[:, 0])
