"""Edge-diffracted paths of the image-source engine (free wall ends and outside corners).

A diffracted path runs from the sonar to an edge (a wedge of :mod:`._wedges`) and back,
optionally with one specular reflection before or after the edge. In image terms a path is
an edge ``E`` between two affine maps: the sonar at emission seen through the source-side
map, ``A_i x(t - tau) + b_i``, and at reception through the receiver-side map,
``A_o x(t) + b_o`` (identity, or the mirror in the wall the sound reflects from); the
retarded delay solves

    |A_o x(t) + b_o - E| + |A_i x(t - tau) + b_i - E| = c tau.

The gain is the uniform theory of diffraction (Kouyoumjian-Pathak, rigid faces) at the
carrier, relative to the engine's spreading: with ``r, r'`` the two legs,

    g = R_via * C * (r + r') / sqrt(r r'),   C = -sum / (2 n sqrt(2 pi k_c)),

rendered as ``g (c tau)**-(p + 1/2) s_d(t - tau)`` where ``p`` is the specular spreading
power and ``s_d`` is :func:`~._config.diffraction_period` (the path signal filtered once
more by the edge's ``sqrt(f_c / f) e^{-i pi/4}``; a complex ``g`` through its quadrature).
For ``2d`` (a line source over a point edge) this is ``sqrt(8 pi k_c)`` times
``G(r') D G-leg(r)``; for ``3d`` the point source over an infinite vertical edge,
``D / sqrt(r r' (r + r'))``. Validity (the sonar in the wedge's air sector, each leg free,
the specular point on its wall) is decided at the sonar's position at reception, like the
specular paths.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mapping.signal import SonarConfig
from mapping.simulate._base import TrajectoryLike
from mapping.simulate.ism._images import mirror_maps
from mapping.simulate.ism._trace import _first_hit
from mapping.simulate.ism._wedges import Wedges, diffracting_wedges, utd_sum, wedge_angle

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

#: Legs shorter than this (metres) do not diffract (the sonar at the edge).
_MIN_LEG_M = 1e-6
#: Angles beyond the air sector by less than this (rad) still count as inside.
_SECTOR_TOL_RAD = 1e-9


@dataclass(frozen=True)
class EdgePaths:
    """Candidate diffracted paths (arrays over paths).

    Attributes
    ----------
    wedge : ndarray of int, shape (P,)
        Index into ``wedges``.
    A_in, b_in, A_out, b_out : ndarray, shapes (P, 2, 2), (P, 2)
        Source-side and receiver-side maps.
    via : ndarray of int, shape (P,)
        Wall of the specular reflection (-1: the edge alone).
    wedges : Wedges
    """

    wedge: IntArray
    A_in: FloatArray
    b_in: FloatArray
    A_out: FloatArray
    b_out: FloatArray
    via: IntArray
    wedges: Wedges

    @property
    def n(self) -> int:
        """Number of candidate paths."""
        return int(self.wedge.size)


def edge_paths(segments: FloatArray, order: int) -> EdgePaths:
    """Every candidate diffracted path of a scene: per wedge, the edge alone (order >= 1) and
    with one reflection in each wall before and after the edge (order 2)."""
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order}")
    wedges = diffracting_wedges(segments)
    WA, Wb = mirror_maps(segments)
    eye, zero = np.eye(2), np.zeros(2)
    rows: list[tuple[int, FloatArray, FloatArray, FloatArray, FloatArray, int]] = []
    for e in range(wedges.count):
        rows.append((e, eye, zero, eye, zero, -1))
        if order == 2:
            for w in range(segments.shape[0]):
                rows.append((e, WA[w], Wb[w], eye, zero, w))
                rows.append((e, eye, zero, WA[w], Wb[w], w))
    cols = list(zip(*rows, strict=True)) if rows else [()] * 6
    return EdgePaths(
        wedge=np.array(cols[0], dtype=np.int64),
        A_in=np.array(cols[1], dtype=np.float64).reshape(-1, 2, 2),
        b_in=np.array(cols[2], dtype=np.float64).reshape(-1, 2),
        A_out=np.array(cols[3], dtype=np.float64).reshape(-1, 2, 2),
        b_out=np.array(cols[4], dtype=np.float64).reshape(-1, 2),
        via=np.array(cols[5], dtype=np.int64),
        wedges=wedges,
    )


def _apply(A: FloatArray, b: FloatArray, xy: FloatArray) -> FloatArray:
    """``A[p] x[m] + b[p]`` -> (P, m, 2)."""
    return np.asarray(xy[None] @ A.transpose(0, 2, 1) + b[:, None, :])


def _leg_free(p: FloatArray, q: FloatArray, segments: FloatArray,
              exclude: IntArray) -> BoolArray:
    """Legs ``p -> q`` (N, 2) that cross no wall strictly between their ends (one wall per
    leg excluded)."""
    c0, dseg = segments[:, 0], segments[:, 1] - segments[:, 0]
    _, w = _first_hit(p, q, c0, dseg, exclude, np.zeros(p.shape[0], dtype=bool))
    return np.asarray(w < 0)


def _via_point(edge: FloatArray, image: FloatArray, wall: FloatArray
               ) -> tuple[FloatArray, BoolArray]:
    """Where the line edge -> image crosses the wall (N, 2), and whether it does so on the
    segment strictly between the two."""
    r = image - edge
    d = wall[:, 1] - wall[:, 0]
    q = wall[:, 0] - edge
    den = r[:, 0] * d[:, 1] - r[:, 1] * d[:, 0]
    ok = np.abs(den) > 1e-15
    den = np.where(ok, den, 1.0)
    s = (q[:, 0] * d[:, 1] - q[:, 1] * d[:, 0]) / den
    u = (q[:, 0] * r[:, 1] - q[:, 1] * r[:, 0]) / den
    ok &= (s > 1e-9) & (s < 1 - 1e-9) & (u >= -1e-9) & (u <= 1 + 1e-9)
    return edge + s[:, None] * r, ok


def edge_validity(paths: EdgePaths, segments: FloatArray, positions_m: FloatArray) -> BoolArray:
    """Whether each diffracted path exists at each sonar position (P, m).

    Both apparent ends (the sonar through each map) lie in the wedge's air sector and no
    further than ``_MIN_LEG_M`` from the edge; the leg edge -> sonar is free; a reflected
    leg meets its wall on the segment, and both of its parts are free.
    """
    pos = np.asarray(positions_m, dtype=np.float64).reshape(-1, 2)
    P, m = paths.n, pos.shape[0]
    if P == 0:
        return np.zeros((0, m), dtype=bool)
    wedges = paths.wedges
    E = wedges.point_m[paths.wedge]  # (P, 2)
    sub = Wedges(E, wedges.face_rad[paths.wedge], wedges.n[paths.wedge],
                 wedges.walls[paths.wedge])
    ok = np.ones((P, m), dtype=bool)
    for A, b in ((paths.A_in, paths.b_in), (paths.A_out, paths.b_out)):
        end = _apply(A, b, pos)
        ok &= wedge_angle(sub, end) <= sub.n[:, None] * math.pi + _SECTOR_TOL_RAD
        ok &= np.linalg.norm(end - E[:, None], axis=2) > _MIN_LEG_M
    Em = np.broadcast_to(E[:, None], (P, m, 2)).reshape(-1, 2)
    x = np.broadcast_to(pos[None], (P, m, 2)).reshape(-1, 2)
    via = np.repeat(paths.via, m)
    direct = via < 0
    flat = ok.ravel()
    if direct.any():
        i = np.flatnonzero(direct & flat)
        flat[i] &= _leg_free(Em[i], x[i], segments, np.full(i.size, -1))
    i = np.flatnonzero(~direct & flat)
    if i.size:
        point, on = _via_point(Em[i], _image_end(paths, pos)[i], segments[via[i]])
        free = on.copy()
        free[on] = _leg_free(Em[i][on], point[on], segments, via[i][on])
        free[free] = _leg_free(point[free], x[i][free], segments, via[i][free])
        flat[i] = free
    return flat.reshape(P, m)


def _image_end(paths: EdgePaths, pos: FloatArray) -> FloatArray:
    """The mirrored apparent end of each path (source side or receiver side), (P * m, 2)."""
    src = _apply(paths.A_in, paths.b_in, pos)
    rcv = _apply(paths.A_out, paths.b_out, pos)
    moved = np.linalg.norm(src - pos[None], axis=2) > 0
    return np.where(moved[..., None], src, rcv).reshape(-1, 2)


#: Number of frequencies (across the main lobe) where the two-shape fit of the diffraction
#: coefficient is made.
_FIT_POINTS = 16


def _fit_basis(config: SonarConfig) -> tuple[FloatArray, ComplexArray, ComplexArray]:
    """Fit frequencies ``f`` (the main lobe of the BPSK spectrum, above 0.1 f_c), the Keller
    shape ``H(f) = sqrt(f_c / f) e^{-i pi/4}`` there, and the projector ``M`` (2, J) of the
    weighted least-squares fit ``T(f) ~ c_1 H(f) + c_2`` (weights: the signal's power)."""
    fc, chip = config.carrier_hz, config.chip_rate_hz
    f = np.linspace(max(fc - chip, 0.1 * fc), fc + chip, _FIT_POINTS + 2)[1:-1]
    w = np.sinc((f - fc) / chip) ** 2
    H = np.sqrt(fc / f) * np.exp(-1j * math.pi / 4)
    basis = np.stack([H, np.ones_like(H)], axis=1) * np.sqrt(w)[:, None]  # (J, 2)
    M = np.linalg.pinv(basis) * np.sqrt(w)[None, :]
    return f, H, np.asarray(M, dtype=np.complex128)


def edge_gains(paths: EdgePaths, valid: BoolArray, reflection: FloatArray,
               positions_m: FloatArray, config: SonarConfig
               ) -> tuple[ComplexArray, ComplexArray]:
    """Complex gains of each path at each position (P, m) with the Keller-shaped signal and
    with the path signal itself; 0 where invalid.

    The UTD coefficient relative to the path signal, ``T(f) = -sum(k L) H(f) / (2 n
    sqrt(2 pi k_c))`` (:func:`~._wedges.utd_sum`, ``L = r r' / (r + r')``), is fitted across
    the signal's band as ``c_1 H(f) + c_2``: far from shadow boundaries ``T`` is the Keller
    shape (``c_2 = 0``), at a boundary it is flat (``c_1 = 0``). Both are multiplied by
    ``R_via (r + r') / sqrt(r r')``.
    """
    pos = np.asarray(positions_m, dtype=np.float64).reshape(-1, 2)
    P, m = paths.n, pos.shape[0]
    if P == 0:
        empty = np.zeros((0, m), dtype=np.complex128)
        return empty, empty
    wedges = paths.wedges
    sub = Wedges(wedges.point_m[paths.wedge], wedges.face_rad[paths.wedge],
                 wedges.n[paths.wedge], wedges.walls[paths.wedge])
    src = _apply(paths.A_in, paths.b_in, pos)
    rcv = _apply(paths.A_out, paths.b_out, pos)
    r_in = np.maximum(np.linalg.norm(src - sub.point_m[:, None], axis=2), _MIN_LEG_M)
    r_out = np.maximum(np.linalg.norm(rcv - sub.point_m[:, None], axis=2), _MIN_LEG_M)
    i, j = np.nonzero(valid)  # the UTD sum only where the path exists
    n = sub.n[i][:, None]
    phi_src = np.minimum(wedge_angle(sub, src)[i, j], sub.n[i] * math.pi)[:, None]
    phi = np.minimum(wedge_angle(sub, rcv)[i, j], sub.n[i] * math.pi)[:, None]
    f, H, M = _fit_basis(config)
    k = 2 * math.pi * f / config.sound_speed_m_s
    k_c = 2 * math.pi * config.carrier_hz / config.sound_speed_m_s
    R = np.asarray(reflection, dtype=np.float64)
    a, b = r_in[i, j], r_out[i, j]
    L = (a * b / (a + b))[:, None]
    total = utd_sum(n, phi, phi_src, k * L, R[sub.walls[i, 0]][:, None],
                    R[sub.walls[i, 1]][:, None])  # (N, J)
    coeff = (-total * H / (2 * n * math.sqrt(2 * math.pi * k_c))) @ M.T  # (N, 2)
    r_via = np.where(paths.via >= 0, R[np.maximum(paths.via, 0)], 1.0)[i]
    scale = r_via * (a + b) / np.sqrt(a * b)
    keller = np.zeros((P, m), dtype=np.complex128)
    flat = np.zeros((P, m), dtype=np.complex128)
    keller[i, j] = scale * coeff[:, 0]
    flat[i, j] = scale * coeff[:, 1]
    return keller, flat


def edge_delay(paths: EdgePaths, trajectory: TrajectoryLike, t_s: FloatArray, c: float,
               newton_steps: int = 3) -> tuple[FloatArray, FloatArray]:
    """Retarded delay of each diffracted path at reception times ``t_s`` and its derivative.

    Solves ``F = |A_o x(t) + b_o - E| + |A_i x(t - tau) + b_i - E| - c tau = 0`` by Newton
    from the static delay; ``d tau / dt = -F_t / F_tau``. Returns two (P, m) arrays.
    """
    t = np.asarray(t_s, dtype=np.float64).ravel()
    E = paths.wedges.point_m[paths.wedge][:, None, :]  # (P, 1, 2)
    x, v = trajectory.position(t), trajectory.velocity(t)
    d_out = _apply(paths.A_out, paths.b_out, x) - E
    r_out = np.maximum(np.linalg.norm(d_out, axis=2), _MIN_LEG_M)
    u_out = d_out / r_out[..., None]
    tau = (r_out + np.linalg.norm(_apply(paths.A_in, paths.b_in, x) - E, axis=2)) / c
    for step in range(newton_steps + 1):
        te = (t[None, :] - tau).ravel()
        xe = trajectory.position(te).reshape(tau.shape + (2,))
        ve = trajectory.velocity(te).reshape(tau.shape + (2,))
        d_in = xe @ paths.A_in.transpose(0, 2, 1) + paths.b_in[:, None, :] - E
        r_in = np.maximum(np.linalg.norm(d_in, axis=2), _MIN_LEG_M)
        av_in = np.sum(d_in / r_in[..., None] * (ve @ paths.A_in.transpose(0, 2, 1)), axis=2)
        f_tau = -av_in - c
        if step == newton_steps:
            break
        tau = tau - (r_out + r_in - c * tau) / f_tau
    av_out = np.sum(u_out * (v[None] @ paths.A_out.transpose(0, 2, 1)), axis=2)
    return tau, -(av_out + av_in) / f_tau


def kept_gains(paths: EdgePaths, magnitude: FloatArray, positions_m: FloatArray,
               spread_power: float, max_path_m: float, amplitude_floor: float) -> BoolArray:
    """Where a path is kept: no longer than ``max_path_m`` and its amplitude ``|g| L**-(p +
    1/2)`` (``magnitude`` is ``|g|``, relative to a rigid 1 m specular path) at least
    ``amplitude_floor``."""
    pos = np.asarray(positions_m, dtype=np.float64).reshape(-1, 2)
    E = paths.wedges.point_m[paths.wedge][:, None, :]
    length = (np.linalg.norm(_apply(paths.A_in, paths.b_in, pos) - E, axis=2)
              + np.linalg.norm(_apply(paths.A_out, paths.b_out, pos) - E, axis=2))
    amp = np.asarray(magnitude) * np.maximum(length, _MIN_LEG_M) ** (-(spread_power + 0.5))
    return np.asarray((length <= max_path_m) & (amp >= amplitude_floor) & (magnitude > 0))
