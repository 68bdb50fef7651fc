"""Geometry of specular and edge-diffracted paths, and the geometric truth of image-source
paths; part of :mod:`mapping.simulate.fdtd_compare`, which re-exports it."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.compare._paths import fdtd_length_m
from mapping.signal import SonarConfig
from mapping.simulate.fdtd import FdtdConfig
from mapping.simulate.ism import free_wall_ends

FloatArray = NDArray[np.float64]

#: Leg parameters closer than this to a leg's ends do not count as a wall crossing.
_END_TOL = 1e-9


# ---- geometry of specular and edge-diffracted paths ------------------------------------------
def _segments(segments_m: ArrayLike) -> FloatArray:
    seg = np.asarray(segments_m, dtype=np.float64)
    if seg.ndim != 3 or seg.shape[1:] != (2, 2) or seg.shape[0] < 1:
        raise ValueError(f"segments_m must have shape (W >= 1, 2, 2), got {seg.shape}")
    if not np.all(np.isfinite(seg)) or np.any(np.hypot(*(seg[:, 1] - seg[:, 0]).T) <= 0):
        raise ValueError("segments_m must be finite with non-zero lengths")
    return seg


def _mirror(point: FloatArray, seg: FloatArray) -> FloatArray:
    a, b = seg
    d = (b - a) / np.hypot(*(b - a))
    r = point - a
    out: FloatArray = a + 2 * np.dot(r, d) * d - r
    return out


def _crossing(p: FloatArray, q: FloatArray, seg: FloatArray) -> tuple[float, float] | None:
    """Parameters (t along p -> q, u along the segment) of the crossing of two lines."""
    a, b = seg
    r, e = q - p, b - a
    den = r[0] * e[1] - r[1] * e[0]
    if abs(den) < 1e-14 * max(1.0, float(np.hypot(*r)) * float(np.hypot(*e))):
        return None
    w = a - p
    return (float((w[0] * e[1] - w[1] * e[0]) / den), float((w[0] * r[1] - w[1] * r[0]) / den))


def _on_segment(p: FloatArray, seg: FloatArray) -> bool:
    a, b = seg
    e = b - a
    u = float(np.clip(np.dot(p - a, e) / np.dot(e, e), 0.0, 1.0))
    return bool(np.hypot(*(a + u * e - p)) <= 1e-9 * max(1.0, float(np.hypot(*e))))


def _inside_corner(wall_a: FloatArray, wall_b: FloatArray, corner: FloatArray,
                   came_from: FloatArray) -> bool:
    """Each wall runs from the corner into the other's half-plane on the side the ray came
    from: the air side of both (an inside corner). At an outside corner one runs away."""
    def side(wall: FloatArray, p: FloatArray) -> float:
        d = wall[1] - wall[0]
        return float(d[0] * (p[1] - wall[0][1]) - d[1] * (p[0] - wall[0][0]))

    def reaches(wall: FloatArray, other: FloatArray) -> bool:
        return any(side(other, end) * side(other, came_from) > 1e-12 for end in wall
                   if np.hypot(*(end - corner)) > 1e-9)

    return reaches(wall_a, wall_b) and reaches(wall_b, wall_a)


def leg_blocked(p: ArrayLike, q: ArrayLike, segments_m: ArrayLike) -> bool:
    """True if the open segment p -> q crosses or touches a wall strictly between its ends."""
    P, Q = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)
    for seg in _segments(segments_m):
        x = _crossing(P, Q, seg)
        if x is not None and _END_TOL < x[0] < 1 - _END_TOL and -1e-12 <= x[1] <= 1 + 1e-12:
            return True
    return False


def specular_path(source_m: ArrayLike, receiver_m: ArrayLike, walls: Sequence[int],
                  segments_m: ArrayLike) -> FloatArray | None:
    """Points of the specular path from a source via ``walls`` (in order) to a receiver.

    Mirror the source through the walls in order (image method), then walk back from the
    receiver towards each image: each leg must meet its wall's line inside the segment, and
    no leg may cross another wall. Bistatic (source and receiver may differ), so it also
    serves the legs of a diffracted path and the retarded geometry of a moving sonar.

    Returns
    -------
    ndarray, shape (len(walls) + 2, 2) or None
        ``[source, s_1, ..., s_n, receiver]``; None if the path does not exist (a specular
        point off its segment, a wall in the way, or two consecutive equal walls).
    """
    seg = _segments(segments_m)
    src = np.asarray(source_m, dtype=np.float64)
    rcv = np.asarray(receiver_m, dtype=np.float64)
    w = [int(x) for x in walls]
    if any(not 0 <= x < seg.shape[0] for x in w):
        raise ValueError(f"walls must be indices in 0..{seg.shape[0] - 1}, got {w}")
    if any(a == b for a, b in itertools.pairwise(w)):
        return None
    images = [src]
    for x in w:
        images.append(_mirror(images[-1], seg[x]))
    pts = [rcv]
    cur = rcv
    for n in range(len(w) - 1, -1, -1):
        hit = _crossing(cur, images[n + 1], seg[w[n]])
        # a leg may have zero length only where it starts on its wall: the second bounce of
        # a corner (a monostatic corner echo returns through the vertex)
        t_min = -_END_TOL if n < len(w) - 1 and _on_segment(cur, seg[w[n]]) else _END_TOL
        if (hit is None or not (t_min <= hit[0] < 1 - _END_TOL)
                or not -_END_TOL <= hit[1] <= 1 + _END_TOL):
            return None
        if hit[0] < _END_TOL and not _inside_corner(seg[w[n + 1]], seg[w[n]], cur, pts[-2]):
            return None  # an outside corner has no two-bounce specular path (issue 15)
        cur = cur + max(hit[0], 0.0) * (images[n + 1] - cur)
        pts.append(cur)
    pts.append(src)
    out = np.array(pts[::-1])
    if any(leg_blocked(a, b, seg) for a, b in itertools.pairwise(out)):
        return None
    return out


def path_length_m(points_m: ArrayLike) -> float:
    """Length of a polyline."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    return float(np.sum(np.hypot(*np.diff(p, axis=0).T)))


@dataclass(frozen=True)
class EdgePath:
    """One path via a free wall end (edge diffraction), source -> ... -> edge -> ... -> receiver.

    Attributes
    ----------
    wall : int
        Wall whose free end diffracts.
    edge_m : tuple of float
        The free end.
    walls_in, walls_out : tuple of int
        Specular reflections before and after the edge (source side, receiver side).
    points_m : ndarray, shape (n, 2)
        The polyline from source to receiver.
    length_m : float
        Path length (the heat map shows ``length_m / 2`` as range).
    departure_rad, arrival_rad : float
        Angles in [0, pi] from the velocity to the first leg and to the direction the sound
        arrives from.
    heatmap_angle_rad : float
        ``arccos`` of the mean of the two cosines: where the Doppler heat map puts it.
    """

    wall: int
    edge_m: tuple[float, float]
    walls_in: tuple[int, ...]
    walls_out: tuple[int, ...]
    points_m: FloatArray
    length_m: float
    departure_rad: float
    arrival_rad: float
    heatmap_angle_rad: float

    @property
    def range_m(self) -> float:
        """Heat-map range: half the path length."""
        return self.length_m / 2


def _angle_to(v: FloatArray, d: FloatArray) -> float:
    return float(np.arccos(np.clip(np.dot(v, d) / (np.hypot(*v) * np.hypot(*d)), -1.0, 1.0)))


def path_angles_rad(points_m: ArrayLike, velocity: ArrayLike) -> tuple[float, float, float]:
    """Departure angle, arrival angle (both from the velocity, in [0, pi]) and heat-map angle
    (``arccos`` of their mean cosine) of a polyline path from source to receiver."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    v = np.asarray(velocity, dtype=np.float64)
    if p.shape[0] < 2 or not np.hypot(*v) > 0:
        raise ValueError("points_m needs >= 2 points and velocity must be non-zero")
    dep = _angle_to(v, p[1] - p[0])
    arr = _angle_to(v, p[-2] - p[-1])
    return dep, arr, float(np.arccos(np.clip((np.cos(dep) + np.cos(arr)) / 2, -1.0, 1.0)))


def _wall_sequences(n_walls: int, max_reflections: int) -> list[tuple[int, ...]]:
    out: list[tuple[int, ...]] = []
    for k in range(max_reflections + 1):
        out += [s for s in itertools.product(range(n_walls), repeat=k)
                if all(a != b for a, b in itertools.pairwise(s))]
    return out


def edge_diffraction_paths(segments_m: ArrayLike, source_m: ArrayLike, receiver_m: ArrayLike,
                           velocity: ArrayLike, max_reflections: int = 1,
                           max_length_m: float = math.inf) -> list[EdgePath]:
    """Every path source -> (reflections) -> free wall end -> (reflections) -> receiver.

    Each leg into and out of the edge is a specular path (:func:`specular_path`) between the
    sonar and the wall end with up to ``max_reflections`` reflections; the wall that owns the
    end does not block its own end. Sorted by length.

    Parameters
    ----------
    segments_m : array (W, 2, 2)
    source_m, receiver_m : array (2,)
        Emission and reception points (equal for a static sonar; for a moving one the
        emission point is the position one delay earlier, see :func:`retarded`).
    velocity : array (2,)
        Direction of travel (angles are measured from it).
    max_reflections : int
        Reflections per leg, 0..4.
    max_length_m : float
        Longest path kept.
    """
    seg = _segments(segments_m)
    if not 0 <= max_reflections <= 4:
        raise ValueError(f"max_reflections must be in 0..4, got {max_reflections}")
    src = np.asarray(source_m, dtype=np.float64)
    rcv = np.asarray(receiver_m, dtype=np.float64)
    vel = np.asarray(velocity, dtype=np.float64)
    seqs = _wall_sequences(seg.shape[0], max_reflections)
    out: list[EdgePath] = []
    for wall, end in free_wall_ends(seg):
        # the wall owning the end touches the leg only at the end itself, at leg parameter
        # 1 (into the edge) or 0 (out of it), which leg_blocked ignores
        legs_in = [(s, p) for s in seqs if (p := specular_path(src, end, s, seg)) is not None]
        legs_out = [(s, p) for s in seqs if (p := specular_path(end, rcv, s, seg)) is not None]
        for (s_in, p_in), (s_out, p_out) in itertools.product(legs_in, legs_out):
            pts = np.concatenate([p_in, p_out[1:]])
            length = path_length_m(pts)
            if length > max_length_m:
                continue
            dep, arr, hm = path_angles_rad(pts, vel)
            out.append(EdgePath(wall=wall, edge_m=(float(end[0]), float(end[1])),
                                walls_in=s_in, walls_out=s_out, points_m=pts, length_m=length,
                                departure_rad=dep, arrival_rad=arr, heatmap_angle_rad=hm))
    out.sort(key=lambda e: e.length_m)
    return out


def retarded(length_at: Callable[[FloatArray, FloatArray], float | None],
             position_at: Callable[[float], FloatArray], t_s: float, c: float,
             n_iter: int = 6) -> tuple[float, FloatArray] | None:
    """Retarded path length of a moving sonar: the length ``L`` with ``L = c tau`` for
    emission at ``t_s - tau`` and reception at ``t_s``.

    ``length_at(source, receiver)`` gives the path length between an emission and a reception
    point (None: the path does not exist); fixed-point iteration (contracts by v/c per step).
    Returns ``(L, emission point)`` or None.
    """
    rcv = np.asarray(position_at(t_s), dtype=np.float64)
    length = length_at(rcv, rcv)
    if length is None:
        return None
    src = rcv
    for _ in range(n_iter):
        src = np.asarray(position_at(t_s - length / c), dtype=np.float64)
        new = length_at(src, rcv)
        if new is None:
            return None
        length = new
    return length, src


# ---- geometric truth of the image-source paths ----------------------------------------------
@dataclass(frozen=True)
class GeometricEcho:
    """Where a specular path (wall sequence) of a moving sonar shows up, from geometry alone.

    Attributes
    ----------
    walls : tuple of int
    range_m : float
        Half the retarded path length (emission one delay before reception).
    fdtd_range_m : float
        The same with every leg at the grid's group velocity at the carrier
        (:func:`fdtd_length_m`): where the FDTD's envelope lands.
    heatmap_angle_rad : float
        Mean-cosine angle of departure and arrival (:func:`path_angles_rad`).
    direction_rad : float
        Direction of the last leg in the grid (for :func:`render_paths`).
    points_m : ndarray
        The monostatic polyline at the reception point.
    """

    walls: tuple[int, ...]
    range_m: float
    fdtd_range_m: float
    heatmap_angle_rad: float
    direction_rad: float
    points_m: FloatArray


def image_point(point_m: ArrayLike, walls: Sequence[int], segments_m: ArrayLike) -> FloatArray:
    """Image of a point mirrored in the walls' lines in order (the image method)."""
    seg = _segments(segments_m)
    p = np.asarray(point_m, dtype=np.float64)
    for w in walls:
        p = _mirror(p, seg[int(w)])
    return p


def specular_echo(segments_m: ArrayLike, walls: Sequence[int],
                  position_at: Callable[[float], FloatArray], velocity: ArrayLike, t_s: float,
                  sonar: SonarConfig, fdtd: FdtdConfig) -> GeometricEcho | None:
    """Geometric truth of one specular path heard at ``t_s`` (None if it does not exist).

    Independent of the image-source engine's Newton solver and validity trace. The path
    exists if the monostatic specular path at the reception point does
    (:func:`specular_path`; the image-source engine decides validity there too). Its
    retarded length solves ``L = |x(t) - image(x(t - L / c))|`` by fixed-point iteration
    (:func:`retarded`); the departure/arrival angles and the grid's extra length
    (:func:`fdtd_length_m` minus the length) come from the monostatic path, which differs
    from the bistatic one by ``v tau`` (centimetres).
    """
    seg = _segments(segments_m)
    c = fdtd.speed(sonar)
    rcv = np.asarray(position_at(t_s), dtype=np.float64)
    pts = specular_path(rcv, rcv, walls, seg)
    if pts is None:
        return None

    def length(s: FloatArray, r: FloatArray) -> float:
        return float(np.hypot(*(r - image_point(s, walls, seg))))

    sol = retarded(length, position_at, t_s, c)
    if sol is None:  # pragma: no cover - length() always returns a number
        return None
    total = sol[0]
    extra = fdtd_length_m(pts, sonar.carrier_hz, fdtd, c) - path_length_m(pts)
    _, _, hm = path_angles_rad(pts, velocity)
    d = pts[-2] - pts[-1]
    return GeometricEcho(walls=tuple(int(w) for w in walls), range_m=total / 2,
                         fdtd_range_m=(total + extra) / 2, heatmap_angle_rad=hm,
                         direction_rad=float(math.atan2(d[1], d[0])), points_m=pts)


def edge_echo_range_m(segments_m: ArrayLike, edge: EdgePath,
                      position_at: Callable[[float], FloatArray], t_s: float,
                      sonar: SonarConfig, fdtd: FdtdConfig) -> tuple[float, float] | None:
    """Heat-map range of an edge-diffracted path for a moving sonar: half its retarded length
    (emission one delay before reception, same walls and edge), and the same with each leg
    at the grid's group velocity at the carrier (:func:`fdtd_length_m`). None if the path
    does not exist for the emission point."""
    seg = _segments(segments_m)
    end = np.asarray(edge.edge_m, dtype=np.float64)
    c = fdtd.speed(sonar)

    def polyline(s: FloatArray, r: FloatArray) -> FloatArray | None:
        a = specular_path(s, end, edge.walls_in, seg)
        b = specular_path(end, r, edge.walls_out, seg)
        return None if a is None or b is None else np.concatenate([a, b[1:]])

    def length(s: FloatArray, r: FloatArray) -> float | None:
        p = polyline(s, r)
        return None if p is None else path_length_m(p)

    sol = retarded(length, position_at, t_s, c)
    if sol is None:
        return None
    pts = polyline(sol[1], np.asarray(position_at(t_s), dtype=np.float64))
    if pts is None:
        return None
    return sol[0] / 2, fdtd_length_m(pts, sonar.carrier_hz, fdtd, c) / 2


def nearest_prediction(n_theta: float, n_tau: float,
                       predicted: Sequence[tuple[float, float]]) -> tuple[int, float, float]:
    """Which predicted heat-map cell ``(angle bin, range bin)`` lies nearest a cell (Euclidean
    in bin units); returns its index and the signed offsets ``(d_angle, d_range)`` of the cell
    from it."""
    if len(predicted) == 0:
        raise ValueError("predicted must not be empty")
    p = np.asarray(predicted, dtype=np.float64).reshape(-1, 2)
    i = int(np.argmin((p[:, 0] - n_theta) ** 2 + (p[:, 1] - n_tau) ** 2))
    return i, float(n_theta - p[i, 0]), float(n_tau - p[i, 1])


def valid_wall_sequences(segments_m: ArrayLike, position_m: ArrayLike, max_order: int,
                         max_length_m: float) -> list[tuple[int, ...]]:
    """Brute force: every wall sequence up to ``max_order`` with a valid monostatic specular
    path from ``position_m`` no longer than ``max_length_m`` (a check of the image-source
    engine's pruned beam tracing; exponential in the order, for small scenes)."""
    seg = _segments(segments_m)
    if not 1 <= max_order <= 12:
        raise ValueError(f"max_order must be in 1..12, got {max_order}")
    p = np.asarray(position_m, dtype=np.float64)
    out = []
    for walls in _wall_sequences(seg.shape[0], max_order):
        if not walls:
            continue
        pts = specular_path(p, p, walls, seg)
        if pts is not None and path_length_m(pts) <= max_length_m:
            out.append(walls)
    return out
