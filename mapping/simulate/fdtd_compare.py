"""Comparing the FDTD reference with the image-source engine (paper Sec. 3 against Sec. 2).

The two engines hear the same scene differently in two known ways, and this module holds the
computation that accounts for both:

1. **Grid dispersion and band.** Every FDTD echo has travelled its whole path through the
   grid, so it arrives late by the grid's dispersion along its own direction, and only the
   band the FDTD injected is present. :func:`render_paths` rebuilds an image-source block path
   by path from its path table (delay and Doppler factor at the block midpoint, amplitude,
   the 2-D signal period), band-limited by the FDTD's injection tapers (:func:`grid_band`)
   and, per path, with the phase ``exp(-i (k_num(f, phi) - k) L)`` of its length ``L`` and
   direction ``phi`` (:func:`dispersion_phase`). :func:`fdtd_length_m` predicts where the
   envelope of a multi-leg path lands (each leg at the grid's group velocity along it).
2. **Paths the image-source model leaves out.** Diffraction at the free end of a wall: sound
   goes from the source (possibly via specular reflections) to the wall end and from there
   (possibly via reflections) to the receiver. :func:`free_wall_ends` finds the ends,
   :func:`specular_path` finds a bistatic specular path with its validity and occlusion, and
   :func:`edge_diffraction_paths` lists the diffracted paths with their heat-map range and
   Doppler angle (Keller's geometrical theory of diffraction: the edge re-radiates in all
   directions, so any leg into and out of it is a path; only its geometry is computed
   here, not its amplitude).

Heat-map bookkeeping: :func:`heatmap_angle_rad` (the angle a path shows in the Doppler heat
map of eq. 1: ``cos theta = (D - 1) c / (2 v)``, the mean of the departure and arrival
cosines), :func:`local_maxima` and :func:`window_peak`.

:func:`compare_block` runs both engines on one block of a scene and returns the waveforms,
the rebuilt image-source block and the geometric truth of every path
(:class:`BlockComparison`); :func:`comparison_heatmaps` and :func:`residual_waveform` turn it
into heat maps. Everything else is pure numpy.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.heatmap import HeatMap, doppler_heatmap
from mapping.signal import SonarConfig
from mapping.simulate.base import PathTable, SceneLike, TrajectoryLike
from mapping.simulate.fdtd_config import FdtdConfig, injected_band
from mapping.simulate.fdtd_dispersion import (
    FdtdReport,
    numerical_group_velocity,
    numerical_wavenumber,
    source_filter,
)
from mapping.simulate.ism import IsmConfig, iter_ism_blocks, signal_period

FloatArray = NDArray[np.float64]

#: Leg parameters closer than this to a leg's ends do not count as a wall crossing.
_END_TOL = 1e-9


# ---- heat-map bookkeeping -------------------------------------------------------------------
def heatmap_angle_rad(doppler_factor: ArrayLike, speed_m_s: float, c: float) -> FloatArray:
    """Angle a path shows in the Doppler heat map (paper eq. 1), from its Doppler factor.

    The bank of eq. 1 compensates ``D = 1 + 2 v cos(theta) / c``; a path with Doppler factor
    ``D`` peaks at ``theta = arccos((D - 1) c / (2 v))``. For a path that leaves at angle
    ``a`` and returns from angle ``b`` (both from the velocity) ``D - 1 = v (cos a + cos b) /
    c``, so ``cos theta`` is the mean of the two cosines.

    Raises
    ------
    ValueError
        ``speed_m_s`` zero or not finite, ``c`` not positive.
    """
    if not (math.isfinite(speed_m_s) and speed_m_s != 0):
        raise ValueError(f"speed_m_s must be finite and non-zero, got {speed_m_s}")
    if not c > 0:
        raise ValueError(f"c must be > 0, got {c}")
    d = np.asarray(doppler_factor, dtype=np.float64)
    out: FloatArray = np.arccos(np.clip((d - 1.0) * c / (2.0 * speed_m_s), -1.0, 1.0))
    return out


def local_maxima(H: ArrayLike, n: int, n_range: int | None = None) -> list[tuple[int, int, float]]:
    """The ``n`` strongest strict local maxima of a heat map (3 x 3 neighbourhood).

    Parameters
    ----------
    H : array, shape (n_dirs, P)
        Heat map (rows: angles, columns: range lags).
    n : int
        How many to return (fewer if the map has fewer), >= 1.
    n_range : int or None
        Only columns ``< n_range`` count (None: all). Ranges are circular (the correlation is),
        the angle axis is mirrored at its ends (the Doppler pattern is symmetric about 0 and
        pi), as in :func:`mapping.heatmap.find_peak`.

    Returns
    -------
    list of (n_theta, n_tau, value)
        Strongest first.
    """
    A = np.asarray(H, dtype=np.float64)
    if A.ndim != 2 or A.shape[0] < 2 or A.shape[1] < 3:
        raise ValueError(f"H must be 2-D with >= 2 rows and >= 3 columns, got {A.shape}")
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    m = A.shape[1] if n_range is None else int(n_range)
    if not 1 <= m <= A.shape[1]:
        raise ValueError(f"n_range must be in 1..{A.shape[1]}, got {n_range}")
    pad = np.pad(A, ((1, 1), (0, 0)), mode="reflect")
    neighbours = np.stack([np.roll(pad, (di, dj), axis=(0, 1))[1:-1]
                           for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)])
    is_max = A > neighbours.max(axis=0)
    is_max[:, m:] = False
    idx = np.argwhere(is_max)
    vals = A[is_max]
    order = np.argsort(-vals, kind="stable")[:n]
    return [(int(idx[j, 0]), int(idx[j, 1]), float(vals[j])) for j in order]


def window_peak(H: ArrayLike, n_theta: int, n_tau: int, half_theta: int,
                half_tau: int) -> tuple[int, int, float]:
    """Strongest cell of ``H`` within ``+-half_theta`` rows and ``+-half_tau`` columns of a cell.

    The window is clipped at the angle axis' ends and wraps around in range (circular lags).
    Returns ``(n_theta, n_tau, value)``.
    """
    A = np.asarray(H, dtype=np.float64)
    if A.ndim != 2:
        raise ValueError(f"H must be 2-D, got shape {A.shape}")
    if half_theta < 0 or half_tau < 0:
        raise ValueError(f"half_theta and half_tau must be >= 0, got {half_theta}, {half_tau}")
    if not 0 <= n_theta < A.shape[0]:
        raise ValueError(f"n_theta must be in 0..{A.shape[0] - 1}, got {n_theta}")
    rows = np.arange(max(n_theta - half_theta, 0), min(n_theta + half_theta, A.shape[0] - 1) + 1)
    cols = np.arange(n_tau - half_tau, n_tau + half_tau + 1) % A.shape[1]
    sub = A[np.ix_(rows, cols)]
    i, j = np.unravel_index(int(np.argmax(sub)), sub.shape)
    return int(rows[i]), int(cols[j]), float(sub[i, j])


# ---- band and dispersion of the FDTD --------------------------------------------------------
def grid_band(f_hz: ArrayLike, sonar: SonarConfig, fdtd: FdtdConfig) -> FloatArray:
    """Magnitude response of the FDTD's injection tapers (high-pass below 0.1 f_c,
    raised-cosine low-pass to the injected band edge), normalised to a peak of 1: the
    :func:`~mapping.simulate.fdtd_dispersion.source_filter` without its ``1/(i w)`` and gain."""
    f = np.asarray(f_hz, dtype=np.float64)
    g = np.abs(source_filter(f, sonar, fdtd) * 2 * np.pi * f)
    peak = float(g.max()) if g.size else 0.0
    if not peak > 0:
        raise ValueError("f_hz must contain at least one frequency inside the injected band")
    out: FloatArray = g / peak
    return out


def dispersion_phase(f_hz: ArrayLike, length_m: float, direction_rad: float,
                     sonar: SonarConfig, fdtd: FdtdConfig) -> NDArray[np.complex128]:
    """Phase the grid adds over a straight path: ``exp(-i (k_num(f, phi) - k) L)``.

    ``k_num`` is the staggered scheme's wavenumber along ``direction_rad``
    (:func:`~mapping.simulate.fdtd_dispersion.numerical_wavenumber`); numpy's
    ``e^{+i w t}`` convention, so a slower grid delays. Outside the injected band
    ``(0, f_max)`` the phase is 1 (nothing was injected there).
    """
    c = fdtd.speed(sonar)
    f = np.asarray(f_hz, dtype=np.float64)
    _, f_max = injected_band(sonar, fdtd)
    k = 2 * np.pi * f / c
    kn = np.array([numerical_wavenumber(float(fi), direction_rad, fdtd.grid_step_m,
                                        fdtd.time_step_s, c) if 0 < fi < f_max else float(ki)
                   for fi, ki in zip(f.ravel(), k.ravel(), strict=True)]).reshape(f.shape)
    out: NDArray[np.complex128] = np.exp(-1j * (kn - k) * length_m)
    return out


def fdtd_length_m(points_m: ArrayLike, freq_hz: float, fdtd: FdtdConfig, c: float) -> float:
    """Length a polyline path appears to have in the FDTD: each leg scaled by
    ``c / v_g(freq_hz, leg direction)``, the grid's group velocity at ``freq_hz``.

    An envelope at ``freq_hz`` along the path arrives at ``fdtd_length_m / c`` instead of
    ``length / c``.
    """
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    if p.shape[0] < 2:
        raise ValueError(f"points_m must hold >= 2 points, got {p.shape[0]}")
    total = 0.0
    for a, b in itertools.pairwise(p):
        d = b - a
        length = float(np.hypot(d[0], d[1]))
        if length == 0:
            continue
        vg = numerical_group_velocity(freq_hz, math.atan2(d[1], d[0]), fdtd.grid_step_m,
                                      fdtd.time_step_s, c)
        total += length * c / vg
    return total


def render_paths(paths: PathTable, direction_rad: ArrayLike | None, sonar: SonarConfig,
                 fdtd: FdtdConfig, block_index: int, oversample: int = 32) -> FloatArray:
    """Image-source block ``block_index`` rebuilt path by path, as the FDTD grid would carry it.

    Path i contributes ``a_i s2d(t - tau_i(t))`` with ``tau_i(t) = tau_i + (1 - D_i)(t -
    t_mid)`` (delay and Doppler factor at the block midpoint ``t_mid``, as in the path
    table), ``s2d`` the 2-D signal period (:func:`mapping.simulate.ism.signal_period`,
    spreading ``"2d"``) band-limited by :func:`grid_band` and read off an ``oversample``-times
    finer periodic grid by linear interpolation.

    Parameters
    ----------
    paths : PathTable
        The image-source engine's ground truth for the block (``spreading="2d"``).
    direction_rad : array (n_paths,) or None
        Direction of each path in the grid (e.g. of its image seen from the receiver); the
        grid-dispersion phase of its length ``c tau_i`` along that direction is applied
        (:func:`dispersion_phase`). One direction per path is exact when every leg has the
        same dispersion, i.e. walls parallel to the grid axes or its diagonals (mirroring in
        them keeps ``|cos|`` and ``|sin|`` of a direction, or swaps them). None: no dispersion.
    sonar, fdtd : SonarConfig, FdtdConfig
    block_index : int
        Block k spans samples ``k B .. (k + 1) B - 1``.
    oversample : int
        Fineness of the interpolation grid (>= 1).
    """
    if oversample < 1:
        raise ValueError(f"oversample must be >= 1, got {oversample}")
    if block_index < 0:
        raise ValueError(f"block_index must be >= 0, got {block_index}")
    n_paths = int(paths.delay_s.size)
    dirs = None if direction_rad is None else np.asarray(direction_rad, dtype=np.float64)
    if dirs is not None and dirs.shape != (n_paths,):
        raise ValueError(f"direction_rad must have shape ({n_paths},), got {dirs.shape}")
    c = fdtd.speed(sonar)
    period = signal_period(sonar, "2d")
    p = period.size
    fs = sonar.fs_hz
    f: FloatArray = np.fft.rfftfreq(p, 1.0 / fs).astype(np.float64)
    spec = np.fft.rfft(period) * grid_band(f, sonar, fdtd)
    B = sonar.block_samples
    t = (block_index * B + np.arange(B)) / fs
    t_mid = (block_index + 0.5) * B / fs
    fine_n = p * oversample
    out = np.zeros(B)
    for i in range(n_paths):
        s = spec
        if dirs is not None:
            s = spec * dispersion_phase(f, c * float(paths.delay_s[i]), float(dirs[i]), sonar,
                                        fdtd)
        fine = np.fft.irfft(s, n=fine_n) * oversample
        tau = paths.delay_s[i] + (1.0 - paths.doppler_factor[i]) * (t - t_mid)
        pos = ((t - tau) * fs * oversample) % fine_n
        i0 = np.floor(pos).astype(np.int64)
        w = pos - i0
        out += paths.amplitude[i] * ((1 - w) * fine[i0 % fine_n] + w * fine[(i0 + 1) % fine_n])
    return out


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


def free_wall_ends(segments_m: ArrayLike, tol_m: float = 1e-6) -> list[tuple[int, FloatArray]]:
    """End points of walls that touch no other wall (where a wall stops in the open).

    Returns ``[(wall index, end point), ...]``; an end within ``tol_m`` of another wall
    (its end or its interior: a corner or a T-junction) is not free.
    """
    seg = _segments(segments_m)
    out: list[tuple[int, FloatArray]] = []
    for i in range(seg.shape[0]):
        for end in seg[i]:
            touching = False
            for j in range(seg.shape[0]):
                if j == i:
                    continue
                a, b = seg[j]
                e = b - a
                u = float(np.clip(np.dot(end - a, e) / np.dot(e, e), 0.0, 1.0))
                if np.hypot(*(a + u * e - end)) <= tol_m:
                    touching = True
                    break
            if not touching:
                out.append((i, end.copy()))
    return out


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


# ---- both engines on one block ------------------------------------------------------------
@dataclass(frozen=True)
class BlockComparison:
    """One block of a scene through both engines, and the geometric truth of its paths.

    Attributes
    ----------
    sonar, fdtd_config : SonarConfig, FdtdConfig
    block_index : int
    position_m, velocity_m_s : ndarray (2,)
        Sonar at the block midpoint.
    fdtd : ndarray (B,)
        The FDTD block (walls run minus free run).
    ism : ndarray (B,)
        The image-source engine's block (``spreading="2d"``).
    ism_band, ism_dispersed : ndarray (B,)
        The image-source block rebuilt from its path table (:func:`render_paths`),
        band-limited like the FDTD source, without and with the grid dispersion.
    paths : PathTable
        The image-source engine's paths at the midpoint.
    echoes : tuple of GeometricEcho or None
        Per path of ``paths``: its geometric truth (:func:`specular_echo`; None if the path
        does not exist at exactly the midpoint).
    report : FdtdReport
        The FDTD set-up report (points per wavelength, predicted dispersion).
    seconds : dict
        Wall-clock seconds of the two engines (for benchmarks; never asserted).
    """

    sonar: SonarConfig
    fdtd_config: FdtdConfig
    block_index: int
    position_m: FloatArray
    velocity_m_s: FloatArray
    fdtd: FloatArray
    ism: FloatArray
    ism_band: FloatArray
    ism_dispersed: FloatArray
    paths: PathTable
    echoes: tuple[GeometricEcho | None, ...]
    report: FdtdReport
    seconds: dict[str, float]

    @property
    def speed_m_s(self) -> float:
        """Speed at the block midpoint."""
        return float(np.hypot(*self.velocity_m_s))

    @property
    def heading_rad(self) -> float:
        """Direction of travel at the block midpoint."""
        return float(math.atan2(self.velocity_m_s[1], self.velocity_m_s[0]))


def compare_block(scene: SceneLike, trajectory: TrajectoryLike, sonar: SonarConfig,
                  fdtd: FdtdConfig, block_index: int,
                  ism_max_path_m: float | None = None) -> BlockComparison:
    """Run the FDTD and the image-source engine on block ``block_index`` and rebuild the
    image-source block as the grid would carry it.

    The image-source engine uses ``spreading="2d"`` (the FDTD's line source) and keeps
    paths up to ``ism_max_path_m`` (default ``c * fdtd.warmup_s``: what the FDTD has heard
    by the block's start). Each path is rendered with the dispersion along the direction of
    its geometric truth (:func:`specular_echo`), or, where that does not exist at exactly
    the midpoint, along ``heading + angle_to_velocity`` (the mirror image about the heading
    has the same dispersion only for headings along the grid axes or diagonals).

    Warns (``UserWarning``) like :func:`mapping.simulate.fdtd.setup_for_scene` on a grid with
    fewer than ``fdtd.warn_points_per_wavelength`` points per wavelength.
    """
    from mapping.simulate.fdtd import finished_blocks, iter_fdtd, new_state, setup_for_scene

    if fdtd.warmup_s is None and ism_max_path_m is None:
        raise ValueError("give fdtd.warmup_s or ism_max_path_m (which paths both engines hear)")
    c = fdtd.speed(sonar)
    max_path = c * float(fdtd.warmup_s or 0.0) if ism_max_path_m is None else ism_max_path_m
    k = int(block_index)
    t_mid = (k + 0.5) * sonar.block_s
    pos = np.asarray(trajectory.position(np.array([t_mid]))[0], dtype=np.float64)
    vel = np.asarray(trajectory.velocity(np.array([t_mid]))[0], dtype=np.float64)
    t0 = time.perf_counter()
    block = next(iter(iter_ism_blocks(scene, trajectory, sonar, 1,
                                      IsmConfig(spreading="2d", max_path_m=max_path),
                                      np.random.default_rng(0), first_block=k)))
    t1 = time.perf_counter()
    setup = setup_for_scene(scene, trajectory, sonar, fdtd, n_blocks=1, first_block=k)
    state = new_state(setup)
    for _ in iter_fdtd(setup, state):
        pass
    x_fdtd = np.asarray(finished_blocks(setup, state)[0].samples, dtype=np.float64)
    t2 = time.perf_counter()

    def position_at(t: float) -> FloatArray:
        return np.asarray(trajectory.position(np.array([t]))[0], dtype=np.float64)

    seg = scene.segments()
    paths = block.paths
    echoes = tuple(specular_echo(seg, w, position_at, vel, t_mid, sonar, fdtd)
                   for w in paths.walls)
    heading = float(math.atan2(vel[1], vel[0]))
    dirs = np.array([e.direction_rad if e is not None
                     else heading + float(paths.angle_to_velocity_rad[i])
                     for i, e in enumerate(echoes)])
    return BlockComparison(
        sonar=sonar, fdtd_config=fdtd, block_index=k, position_m=np.asarray(pos),
        velocity_m_s=np.asarray(vel), fdtd=x_fdtd,
        ism=np.asarray(block.samples, dtype=np.float64),
        ism_band=render_paths(paths, None, sonar, fdtd, k),
        ism_dispersed=render_paths(paths, dirs, sonar, fdtd, k),
        paths=paths, echoes=echoes, report=setup.report,
        seconds={"ism_block": t1 - t0, "fdtd_block": t2 - t1})


def correlation(a: ArrayLike, b: ArrayLike) -> float:
    """Normalised correlation ``<a, b> / (|a| |b|)`` of two waveforms."""
    x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    den = float(np.linalg.norm(x) * np.linalg.norm(y))
    if x.shape != y.shape or not den > 0:
        raise ValueError("a and b must have the same shape and be non-zero")
    return float(np.dot(x.ravel(), y.ravel()) / den)


def residual_waveform(cmp: BlockComparison) -> FloatArray:
    """FDTD block minus the least-squares multiple of the dispersion-corrected image-source
    block: what the image-source model leaves unexplained (diffraction, amplitude errors)."""
    a = float(np.dot(cmp.fdtd, cmp.ism_dispersed) / np.dot(cmp.ism_dispersed, cmp.ism_dispersed))
    out: FloatArray = cmp.fdtd - a * cmp.ism_dispersed
    return out


def comparison_heatmaps(cmp: BlockComparison) -> dict[str, HeatMap]:
    """Doppler heat maps (paper eq. 1) of the FDTD block, the engine's image-source block, its
    dispersion-corrected rebuild and the residual waveform (:func:`residual_waveform`)."""
    v, s = cmp.speed_m_s, cmp.sonar
    return {"fdtd": doppler_heatmap(cmp.fdtd, v, s), "ism": doppler_heatmap(cmp.ism, v, s),
            "ism_dispersed": doppler_heatmap(cmp.ism_dispersed, v, s),
            "residual": doppler_heatmap(residual_waveform(cmp), v, s)}
