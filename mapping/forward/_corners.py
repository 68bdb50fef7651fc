"""Inside corners of a fitted map as the sonar hears them: one retro-reflection at the vertex.

A monostatic sonar inside a right-angle corner hears one two-bounce echo that travels to the
vertex and back (the corner is a retro-reflector: the image of the sonar in both walls is its
point reflection through the vertex, so the path passes through it). A *fitted* corner is
never exactly 90 deg: its exact image paths then miss the vertex by a fraction of a
millimetre and either vanish (the specular points fall off the segments) or split in two
((i, j) and (j, i) no longer share one image map). Both are artefacts of the fit, not of the
room. :func:`regularize_corners` replaces, for corners within a tolerance of 90 deg whose
walls share an end, every exact order-2 path of the pair by the vertex echo the room gives.
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
    ``(i, j, vertex)`` with i < j and the vertex the midpoint of the two ends."""
    seg = np.asarray(segments_m, dtype=np.float64)
    out = []
    for i in range(seg.shape[0]):
        for j in range(i + 1, seg.shape[0]):
            for ei in range(2):
                for ej in range(2):
                    if math.hypot(*(seg[i, ei] - seg[j, ej])) <= join_m:
                        out.append((i, j, 0.5 * (seg[i, ei] + seg[j, ej])))
    return out


def _far_end(seg: FloatArray, vertex: FloatArray) -> FloatArray:
    d0, d1 = math.hypot(*(seg[0] - vertex)), math.hypot(*(seg[1] - vertex))
    return np.asarray(seg[1] if d0 < d1 else seg[0])


def corner_angle_deg(segments_m: FloatArray, i: int, j: int, vertex: FloatArray) -> float:
    """Angle between walls i and j at their shared ``vertex`` (0-180 deg)."""
    seg = np.asarray(segments_m, dtype=np.float64)
    ea = _far_end(seg[i], vertex) - vertex
    eb = _far_end(seg[j], vertex) - vertex
    cos = float(ea @ eb) / max(float(np.linalg.norm(ea) * np.linalg.norm(eb)), 1e-300)
    return math.degrees(math.acos(min(max(cos, -1.0), 1.0)))


def right_corners(segments_m: FloatArray, tol_deg: float, join_m: float = 0.05
                  ) -> list[tuple[int, int, FloatArray]]:
    """Shared vertices (:func:`shared_vertices`) whose angle is within ``tol_deg`` of 90."""
    return [(i, j, v) for i, j, v in shared_vertices(segments_m, join_m)
            if abs(corner_angle_deg(segments_m, i, j, v) - 90.0) <= tol_deg]


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


def regularize_corners(fields: dict[str, np.ndarray], segments_m: FloatArray,
                       strength: FloatArray, poses: FloatArray,
                       corners: list[tuple[int, int, FloatArray]], speed_m_s: float,
                       sound_speed_m_s: float, spreading_power: float, max_path_m: float,
                       min_amplitude: float) -> dict[str, np.ndarray]:
    """Padded echo arrays (``count``, ``path_m`` (round trip), ``cos_doppler``,
    ``amplitude``, ``order``, ``walls`` (n, k, K), ``points`` (n, k, K, 2), ``bearing``)
    with every order-2 path of each corner's wall pair replaced by its vertex echo.

    The vertex echo: round trip ``L`` retarded as the exact paths are (the sonar's image is
    its point reflection through the vertex, so ``L = |D - v L / c|`` with ``D = 2 (S -
    C)``), amplitude ``s_i s_j / L**p``, Doppler cosine of the direction to the vertex,
    bounce points both at the vertex. Rows stay sorted by path length; padding as before
    (NaN, order 0, walls -1).
    """
    count = fields["count"]
    n, k = fields["path_m"].shape
    kk = fields["walls"].shape[2]
    valid = np.arange(k)[None, :] < count[:, None]
    if kk >= 2 and corners:
        w = fields["walls"]
        for i, j, _ in corners:
            pair = ((fields["order"] == 2)
                    & (((w[:, :, 0] == i) & (w[:, :, 1] == j))
                       | ((w[:, :, 0] == j) & (w[:, :, 1] == i))))
            valid &= ~pair
    m = len(corners)
    if m == 0 or kk < 2:
        return _compact(fields, valid)
    p = np.asarray(poses, dtype=np.float64)
    dist, heard = vertex_paths(segments_m, p, corners)
    heading = p[:, 2]
    sign = -1.0 if speed_m_s < 0 else 1.0
    t = sign * np.stack([np.cos(heading), np.sin(heading)], axis=1)       # travel
    vel = speed_m_s * np.stack([np.cos(heading), np.sin(heading)], axis=1)
    c = sound_speed_m_s
    names = ("path_m", "cos_doppler", "amplitude", "order", "walls", "points", "bearing")
    new: dict[str, list[np.ndarray]] = {key: [] for key in names}
    ok = heard.copy()
    for col, (i, j, vertex) in enumerate(corners):
        q = vertex[None, :] - p[:, :2]                         # sonar -> vertex
        d = np.maximum(dist[:, col], 1e-12)
        u_to = q / d[:, None]
        big_d = -2.0 * q                                        # D = S - I = 2 (S - C)
        a = -vel / c                                            # A v / c with A = -I
        da = np.sum(big_d * a, axis=1)
        aa = np.sum(a * a, axis=1)
        length0 = 2.0 * d
        length = (da + np.sqrt(da * da + (1.0 - aa) * length0 ** 2)) / (1.0 - aa)
        amp = strength[i] * strength[j] / length ** spreading_power
        ok[:, col] &= (length <= max_path_m) & (np.abs(amp) >= min_amplitude) & (d > 1e-6)
        new["path_m"].append(length)
        new["cos_doppler"].append(np.sum(u_to * t, axis=1))
        new["amplitude"].append(amp)
        new["order"].append(np.full(n, 2, dtype=np.int64))
        wl = np.full((n, kk), -1, dtype=np.int64)
        wl[:, 0], wl[:, 1] = i, j
        new["walls"].append(wl)
        pts = np.full((n, kk, 2), np.nan)
        pts[:, :2] = vertex
        new["points"].append(pts)
        new["bearing"].append(np.arctan2(q[:, 1], q[:, 0]))
    merged = {key: np.concatenate([fields[key], np.stack(new[key], axis=1)], axis=1)
              for key in new}
    return _compact(merged, np.concatenate([valid, ok], axis=1))


def _compact(fields: dict[str, np.ndarray], valid: NDArray[np.bool_]) -> dict[str, np.ndarray]:
    """Keep the valid entries of each row, sorted by path length, padded as the kernel pads."""
    key = np.where(valid, fields["path_m"], np.inf)
    order = np.argsort(key, axis=1, kind="stable")
    count = valid.sum(axis=1).astype(np.int64)
    kmax = int(count.max()) if count.size else 0
    order = order[:, :kmax]
    keep = np.arange(kmax)[None, :] < count[:, None]
    out: dict[str, np.ndarray] = {"count": count}
    pads = {"path_m": np.nan, "cos_doppler": np.nan, "amplitude": np.nan, "order": 0,
            "walls": -1, "points": np.nan, "bearing": np.nan}
    for name, pad in pads.items():
        arr = fields[name]
        idx = order.reshape(order.shape + (1,) * (arr.ndim - 2))
        taken = np.take_along_axis(arr, idx, axis=1)
        mask = keep.reshape(keep.shape + (1,) * (arr.ndim - 2))
        out[name] = np.where(mask, taken, pad).astype(arr.dtype)
    return out
