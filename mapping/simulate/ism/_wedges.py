"""Diffracting edges of a 2-D scene and the uniform (UTD) diffraction coefficient of a wedge.

In a plan of thin walls an edge is a point where walls end. Around it the walls' rays cut
the plane into air sectors; a sector wider than pi is a wedge that diffracts (a free wall
end: 2 pi; an outside corner: 3 pi / 2), a narrower one is an inside corner that the image
method already solves exactly. :func:`diffracting_wedges` finds them; :func:`wedge_angle`
measures a point's angle in a wedge; :func:`utd_sum` is the Kouyoumjian-Pathak sum of a
rigid (Neumann) wedge, with Luebbers' reflection factors on the face terms.

Used by :mod:`mapping.simulate.ism._diffraction` and, for the geometry of free wall ends,
by :mod:`mapping.compare` (the one home of :func:`free_wall_ends`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import fresnel

from mapping.simulate.ism._images import _check_segments

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
IntArray = NDArray[np.int64]

#: Air sectors wider than pi by more than this (rad) diffract.
_REFLEX_TOL_RAD = 1e-9
#: Beyond this argument the transition function is its asymptotic series.
_F_ASYMPTOTIC_X = 1e6
#: Closer than this (rad, in the cotangent's argument) to a shadow boundary: its limit.
_POLE_TOL = 1e-9


def _segments(segments_m: ArrayLike) -> FloatArray:
    """The image engine's segment check (:func:`_images._check_segments`), and at least one."""
    seg = _check_segments(np.asarray(segments_m, dtype=np.float64))
    if seg.shape[0] < 1:
        raise ValueError("segments must hold at least one wall, got none")
    return seg


def _distance_to_wall(point: FloatArray, seg: FloatArray) -> tuple[float, float]:
    """Distance from a point to a segment and the segment parameter of the nearest point.

    Where the nearest point is an end, the distance is to that end exactly (``a + 1 * e``
    can miss ``b`` by a rounding error, and then a wall end exactly ``tol_m`` from another
    wall's end counted as free here while the wedge search merged the two into one vertex:
    the clean-clone CI failure of ``test_free_ends_are_the_full_turn_wedges``)."""
    a, b = seg
    e = b - a
    u = float(np.clip(np.dot(point - a, e) / np.dot(e, e), 0.0, 1.0))
    nearest = a if u <= 0.0 else b if u >= 1.0 else a + u * e
    return float(np.hypot(*(nearest - point))), u


def free_wall_ends(segments_m: ArrayLike, tol_m: float = 1e-6) -> list[tuple[int, FloatArray]]:
    """End points of walls that touch no other wall (where a wall stops in the open).

    Returns ``[(wall index, end point), ...]``; an end within ``tol_m`` of another wall
    (its end or its interior: a corner or a T-junction) is not free.
    """
    seg = _segments(segments_m)
    out: list[tuple[int, FloatArray]] = []
    for i in range(seg.shape[0]):
        for end in seg[i]:
            if all(_distance_to_wall(end, seg[j])[0] > tol_m
                   for j in range(seg.shape[0]) if j != i):
                out.append((i, end.copy()))
    return out


@dataclass(frozen=True)
class Wedges:
    """Diffracting wedges of a scene (arrays over wedges).

    Attributes
    ----------
    point_m : ndarray, shape (E, 2)
        The edge.
    face_rad : ndarray, shape (E,)
        Direction of face 0 from the edge; the air sector runs counter-clockwise from it.
    n : ndarray, shape (E,)
        Air-sector angle over pi, in (1, 2]: 2 at a free wall end, 1.5 at a right-angle
        outside corner.
    walls : ndarray of int, shape (E, 2)
        Wall of face 0 and of face n (the same wall at a free end).
    """

    point_m: FloatArray
    face_rad: FloatArray
    n: FloatArray
    walls: IntArray

    @property
    def count(self) -> int:
        """Number of wedges."""
        return int(self.n.size)


def _rays(point: FloatArray, seg: FloatArray, tol_m: float) -> list[tuple[float, int]]:
    """Directions (rad) of the walls leaving ``point``, with their wall ids."""
    out = []
    for j in range(seg.shape[0]):
        dist, _ = _distance_to_wall(point, seg[j])
        if dist > tol_m:
            continue
        for end in seg[j]:
            d = end - point
            if np.hypot(*d) > tol_m:
                out.append((math.atan2(d[1], d[0]), j))
    return out


def diffracting_wedges(segments_m: ArrayLike, tol_m: float = 1e-6) -> Wedges:
    """Every wedge of the scene whose air sector is wider than pi (it diffracts).

    Vertices are the wall end points (merged within ``tol_m``); the walls through a vertex
    (ending there, or passing through it: a T-junction) split the plane into sectors.

    Parameters
    ----------
    segments_m : array, shape (W, 2, 2)
    tol_m : float
        Distance under which a point lies on a wall.
    """
    seg = _segments(segments_m)
    if not tol_m > 0:
        raise ValueError(f"tol_m must be > 0, got {tol_m}")
    vertices: list[FloatArray] = []
    for p in seg.reshape(-1, 2):
        if all(np.hypot(*(p - q)) > tol_m for q in vertices):
            vertices.append(p)
    pts, faces, ns, walls = [], [], [], []
    for p in vertices:
        rays = sorted(_rays(p, seg, tol_m))
        for i, (angle, wall) in enumerate(rays):
            nxt, nwall = rays[(i + 1) % len(rays)]
            gap = (nxt - angle) % (2 * math.pi) or 2 * math.pi
            if gap > math.pi + _REFLEX_TOL_RAD:
                pts.append(p)
                faces.append(angle)
                ns.append(gap / math.pi)
                walls.append((wall, nwall))
    return Wedges(point_m=np.array(pts, dtype=np.float64).reshape(-1, 2),
                  face_rad=np.array(faces, dtype=np.float64),
                  n=np.array(ns, dtype=np.float64),
                  walls=np.array(walls, dtype=np.int64).reshape(-1, 2))


def wedge_angle(wedges: Wedges, points_m: FloatArray) -> FloatArray:
    """Angle of each point seen from each edge, counter-clockwise from face 0, in [0, 2 pi).

    ``points_m`` has shape (E, m, 2) (a point set per wedge) or (m, 2); returns (E, m).
    The point is in the wedge's air sector where the angle is at most ``n pi``.
    """
    p = np.asarray(points_m, dtype=np.float64)
    d = p - wedges.point_m[:, None, :]
    ang = np.arctan2(d[..., 1], d[..., 0]) - wedges.face_rad[:, None]
    return np.asarray(np.mod(ang, 2 * math.pi))


def transition(x: ArrayLike) -> ComplexArray:
    """The UTD transition function ``F(X) = 2 i sqrt(X) e^{iX} int_sqrt(X)^inf e^{-i t^2} dt``.

    ``e^{+i w t}`` convention (outgoing ``e^{-ikr}``, numpy's FFT); F(0) = 0, F -> 1 for
    large X (asymptotic series beyond 1e6).
    """
    X = np.maximum(np.asarray(x, dtype=np.float64), 0.0)
    u = np.sqrt(X)
    s, c = fresnel(u * math.sqrt(2 / math.pi))
    tail = math.sqrt(math.pi / 2) * ((0.5 - c) - 1j * (0.5 - s))
    out = 2j * u * np.exp(1j * X) * tail
    big = X > _F_ASYMPTOTIC_X
    xb = np.where(big, X, 1.0)
    return np.asarray(np.where(big, 1 + 0.5j / xb - 0.75 / xb**2, out), dtype=np.complex128)


def _cot_f(arg: FloatArray, n: FloatArray, beta: FloatArray, sign: int,
           kL: FloatArray) -> ComplexArray:
    """One term ``cot((pi + sign beta) / 2n) F(kL a(beta))`` of the UTD sum, finite at its
    shadow boundary: there its limit ``2n sqrt(pi kL / 2) e^{i pi / 4}`` (the lit side)."""
    N = np.round((beta + sign * math.pi) / (2 * math.pi * n))
    a = 2 * np.cos((2 * math.pi * n * N - beta) / 2) ** 2
    t = np.tan(arg)
    pole = np.abs(np.sin(arg)) < _POLE_TOL
    safe = np.where(pole, 1.0, t)
    generic = transition(kL * a) / safe
    limit = 2 * n * np.sqrt(math.pi * kL / 2) * np.exp(1j * math.pi / 4)
    return np.asarray(np.where(pole, limit, generic), dtype=np.complex128)


def utd_sum(n: ArrayLike, phi: ArrayLike, phi_source: ArrayLike, kL: ArrayLike,
            reflection_0: ArrayLike = 1.0, reflection_n: ArrayLike = 1.0) -> ComplexArray:
    """Kouyoumjian-Pathak sum of a rigid wedge: ``D = -e^{-i pi/4} / (2n sqrt(2 pi k)) * sum``.

    ``sum = D1 + D2 + R_n D3 + R_0 D4``, the four ``cot(.) F(kL a(.))`` terms of the
    incident (``beta = phi - phi_source``) and reflected (``beta = phi + phi_source``)
    shadow boundaries; rigid faces add the reflected terms (Neumann), and Luebbers' factors
    ``R_0``, ``R_n`` scale them for absorbing faces. At a shadow boundary the sum makes the
    diffracted field minus (lit side) or plus (shadow side) half the field that switches off
    there, so the total is continuous.

    Parameters
    ----------
    n : array
        Air-sector angle over pi (1 < n <= 2 here).
    phi, phi_source : array
        Angles of the receiver and of the source from face 0, in [0, n pi].
    kL : array
        Wavenumber times the distance parameter ``L = r r' / (r + r')``.
    reflection_0, reflection_n : array
        Reflection coefficients of the faces.
    """
    n_, ph, ps, kl = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64)
                                           for v in (n, phi, phi_source, kL)))
    minus, plus = ph - ps, ph + ps
    total = (_cot_f((math.pi + minus) / (2 * n_), n_, minus, +1, kl)
             + _cot_f((math.pi - minus) / (2 * n_), n_, minus, -1, kl)
             + np.asarray(reflection_n) * _cot_f((math.pi + plus) / (2 * n_), n_, plus, +1, kl)
             + np.asarray(reflection_0) * _cot_f((math.pi - plus) / (2 * n_), n_, plus, -1, kl))
    return np.asarray(total, dtype=np.complex128)
