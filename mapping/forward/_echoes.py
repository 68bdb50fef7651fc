"""The echo list: specular image-source paths of wall segments seen from a moving sonar.

:class:`WallSet` holds the walls the model knows, :class:`ForwardParams` the limits;
:func:`echoes` gives the :class:`Echoes` of one pose, :func:`echoes_batch` the
:class:`EchoBatch` of many (numba, parallel over poses). The path enumeration and tracing
are the kernel ``_kernels._batch_echoes`` (right corners heard at their vertex included);
this module validates and converts.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.forward._corners import _corner_arrays, right_corners
from mapping.forward._kernels import (
    _batch_echoes,
    _Corners,
    _Limits,
    _Out,
    _serial_echoes,
    _Walls,
)
from mapping.signal import SonarConfig, checked_speed_m_s

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Allowed values of ``ForwardParams.spreading`` and their amplitude exponent p (1 / L**p).
SPREADING_POWER = {"3d": 1.0, "2d": 0.5}
#: Highest reflection order the model enumerates.
MAX_ORDER = 4


@dataclass(frozen=True)
class WallSet:
    """Walls the forward model knows.

    Attributes
    ----------
    segments_m : ndarray, shape (n, 2, 2)
        End points ``[[x0, y0], [x1, y1]]`` in metres; n may be 0.
    strength : ndarray, shape (n,)
        Amplitude reflection factor of each wall (rigid = 1; may be a signed R).
    """

    segments_m: FloatArray
    strength: FloatArray

    def __post_init__(self) -> None:
        seg = np.asarray(self.segments_m, dtype=np.float64)
        if seg.ndim != 3 or seg.shape[1:] != (2, 2):
            raise ValueError(f"WallSet.segments_m must have shape (n, 2, 2), got {seg.shape}")
        if not np.all(np.isfinite(seg)):
            raise ValueError("WallSet.segments_m must be finite")
        if np.any(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1) <= 1e-9):
            raise ValueError("WallSet.segments_m must have non-zero length segments")
        strength = np.asarray(self.strength, dtype=np.float64)
        if strength.shape != (seg.shape[0],) or not np.all(np.isfinite(strength)):
            raise ValueError(
                f"WallSet.strength must be finite with shape ({seg.shape[0]},), "
                f"got shape {strength.shape}"
            )
        seg, strength = seg.copy(), strength.copy()
        seg.setflags(write=False)
        strength.setflags(write=False)
        object.__setattr__(self, "segments_m", seg)
        object.__setattr__(self, "strength", strength)

    @property
    def n(self) -> int:
        """Number of walls."""
        return int(self.strength.size)

    @classmethod
    def from_scene(cls, scene: Any) -> WallSet:
        """Walls of a scene (``scene.segments()``, ``scene.reflection_coefficients()``)."""
        return cls(np.asarray(scene.segments(), dtype=np.float64).reshape(-1, 2, 2),
                   np.asarray(scene.reflection_coefficients(), dtype=np.float64))

    @classmethod
    def from_array(cls, walls_m: ArrayLike, strength: ArrayLike | None = None) -> WallSet:
        """Walls from rows ``x0, y0, x1, y1`` (n, 4); ``strength`` None means rigid (1)."""
        arr = np.asarray(walls_m, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[1] != 4:
            if arr.size == 0:
                arr = arr.reshape(0, 4)
            else:
                raise ValueError(f"walls_m must have shape (n, 4), got {arr.shape}")
        s = np.ones(arr.shape[0]) if strength is None else np.asarray(strength, dtype=np.float64)
        return cls(arr.reshape(-1, 2, 2), s)


@dataclass(frozen=True)
class ForwardParams:
    """Limits of the echo enumeration.

    Attributes
    ----------
    max_order : int
        Highest reflection order enumerated (1..4); see :func:`mapping.forward.required_order`.
    spreading : {"3d", "2d"}
        Amplitude ``1 / L**p`` with L the round-trip path, p = 1 (``3d``, a real robot) or
        1/2 (``2d``, a 2-D simulation), as ``IsmConfig.spreading``.
    max_range_m : float or None
        One-way range cap (half the round trip); None is the unambiguous range c P / (2 fs).
    min_amplitude : float
        Drop echoes whose |amplitude| is below this (heat-map units).
    right_corner_tol_deg : float
        0 (default): exact image paths only. > 0: walls sharing an end (within
        ``corner_join_m``) at an angle within this many degrees of 90 are a right corner,
        heard as one retro-reflection at the vertex instead of their exact order-2 paths,
        which a fitted corner a fraction of a degree off splits or loses
        (:mod:`mapping.forward._corners`). For fitted maps; the simulator keeps 0.
    corner_join_m : float
        How close two wall ends must be to count as one vertex.
    """

    max_order: int = 2
    spreading: str = "3d"
    max_range_m: float | None = None
    min_amplitude: float = 0.0
    right_corner_tol_deg: float = 0.0
    corner_join_m: float = 0.05

    def __post_init__(self) -> None:
        if not isinstance(self.max_order, int | np.integer) or not 1 <= self.max_order <= MAX_ORDER:
            raise ValueError(
                f"ForwardParams.max_order must be an integer in 1..{MAX_ORDER}, "
                f"got {self.max_order!r}")
        if self.spreading not in SPREADING_POWER:
            raise ValueError(
                f"ForwardParams.spreading must be one of {tuple(SPREADING_POWER)}, "
                f"got {self.spreading!r}")
        if self.max_range_m is not None and not (
                math.isfinite(self.max_range_m) and self.max_range_m > 0):
            raise ValueError(
                f"ForwardParams.max_range_m must be None or > 0, got {self.max_range_m!r}")
        if not (math.isfinite(self.min_amplitude) and self.min_amplitude >= 0):
            raise ValueError(
                f"ForwardParams.min_amplitude must be >= 0, got {self.min_amplitude!r}")
        if not (math.isfinite(self.right_corner_tol_deg)
                and 0 <= self.right_corner_tol_deg <= 45):
            raise ValueError("ForwardParams.right_corner_tol_deg must be in [0, 45], "
                             f"got {self.right_corner_tol_deg!r}")
        if not (math.isfinite(self.corner_join_m) and 0 <= self.corner_join_m <= 1):
            raise ValueError(
                f"ForwardParams.corner_join_m must be in [0, 1], got {self.corner_join_m!r}")


#: The default limits (order 2, 3-D spreading, the unambiguous range, no amplitude floor).
DEFAULT_PARAMS = ForwardParams()


@dataclass(frozen=True)
class Echoes:
    """The k specular echoes of one pose, sorted by range.

    Attributes
    ----------
    range_m : ndarray, shape (k,)
        One-way equivalent range: half the retarded round-trip path of the echo heard at the
        block centre (where eq. 1 puts the peak).
    cos_doppler : ndarray, shape (k,)
        ``(cos(departure) + cos(arrival)) / 2`` w.r.t. the direction of travel: the Doppler
        the echo carries (the eq. 1 row that undoes it has ``cos theta = cos_doppler``).
    angle_rad : ndarray, shape (k,)
        ``arccos(clip(cos_doppler))`` in [0, pi]: the heat-map row it lands in (folded).
    amplitude : ndarray, shape (k,)
        Product of the wall strengths over ``L**p`` (heat-map units: a matched unit echo
        peaks at 1).
    order : ndarray of int, shape (k,)
    walls : ndarray of int, shape (k, max_order)
        Wall indices in the order the sound hits them, -1 padded.
    points_m : ndarray, shape (k, max_order, 2)
        Specular points, NaN padded.
    arrival_bearing_rad : ndarray, shape (k,)
        World-frame direction from the robot toward the last specular point.
    spreading : str
        The spreading the amplitudes were computed with (decides the heard waveform when
        rendering).
    """

    range_m: FloatArray
    cos_doppler: FloatArray
    angle_rad: FloatArray
    amplitude: FloatArray
    order: IntArray
    walls: IntArray
    points_m: FloatArray
    arrival_bearing_rad: FloatArray
    spreading: str = field(default="3d")

    @property
    def k(self) -> int:
        """Number of echoes."""
        return int(self.range_m.size)


@dataclass(frozen=True)
class EchoBatch:
    """Echoes of n poses in padded arrays (n, kmax); row i holds ``count[i]`` echoes.

    Fields as :class:`Echoes` with a leading pose axis; padding is NaN for floats, 0 for
    ``order``, -1 for ``walls``. ``echoes_of(i)`` returns pose i as an :class:`Echoes`.
    ``angle_rad`` is computed from ``cos_doppler`` when first read (a particle filter's
    likelihood reads the cosines only; the arccos of every echo of 2000 poses cost about
    3 % of its update).
    """

    count: IntArray
    range_m: FloatArray
    cos_doppler: FloatArray
    amplitude: FloatArray
    order: IntArray
    walls: IntArray
    points_m: FloatArray
    arrival_bearing_rad: FloatArray
    spreading: str = field(default="3d")

    @functools.cached_property
    def angle_rad(self) -> FloatArray:
        """Angle between the echo's direction and the direction of travel (n, kmax)."""
        return np.arccos(np.clip(self.cos_doppler, -1.0, 1.0))

    def echoes_of(self, i: int) -> Echoes:
        """The echoes of pose ``i``."""
        k = int(self.count[i])
        return Echoes(
            self.range_m[i, :k], self.cos_doppler[i, :k], self.angle_rad[i, :k],
            self.amplitude[i, :k], self.order[i, :k], self.walls[i, :k], self.points_m[i, :k],
            self.arrival_bearing_rad[i, :k], self.spreading,
        )


def _kernel_walls(walls: WallSet) -> _Walls:
    """The walls as the kernel sees them (end points, mirror maps, strengths), cached by
    their coordinates and strengths: a filter asks for the same walls several times per
    block (measured: 0.3 ms of a 10 ms update recomputing them)."""
    seg = np.ascontiguousarray(walls.segments_m, dtype=np.float64)
    strength = np.ascontiguousarray(walls.strength, dtype=np.float64)
    return _walls_of(seg.tobytes(), seg.shape, strength.tobytes())


@functools.lru_cache(maxsize=64)
def _walls_of(segments: bytes, shape: tuple[int, ...], strengths: bytes) -> _Walls:
    """:func:`_kernel_walls` of walls given as bytes (read-only arrays, shared between
    calls)."""
    seg = np.frombuffer(segments, dtype=np.float64).reshape(shape)
    d = seg[:, 1] - seg[:, 0]
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.linalg.norm(d, axis=1)[:, None]
    A = np.eye(2)[None] - 2.0 * n[:, :, None] * n[:, None, :]
    b = 2.0 * np.sum(seg[:, 0] * n, axis=1)[:, None] * n
    out = _Walls(np.ascontiguousarray(seg[:, 0]), np.ascontiguousarray(d),
                 np.ascontiguousarray(A), np.ascontiguousarray(b),
                 np.frombuffer(strengths, dtype=np.float64).copy())
    for a in out:
        a.flags.writeable = False
    return out


def _limits(speed_m_s: float, config: SonarConfig, params: ForwardParams) -> _Limits:
    if not isinstance(params, ForwardParams):
        raise ValueError(f"params must be a ForwardParams, got {type(params).__name__}")
    v = checked_speed_m_s(speed_m_s, config)
    c = config.sound_speed_m_s
    max_range = config.max_range_m if params.max_range_m is None else params.max_range_m
    return _Limits(int(params.max_order), 2.0 * float(max_range), float(params.min_amplitude),
                   float(c), SPREADING_POWER[params.spreading], v)


def _check_walls(walls: WallSet) -> None:
    if not isinstance(walls, WallSet):
        raise ValueError(f"walls must be a WallSet, got {type(walls).__name__}")


#: Slots per pose of the first pass of :func:`_run`. A pose rarely hears more than 14 paths
#: (measured on the benchmark's maps, particle clouds of 2000: median of the most per call
#: 5-10, largest 14), while the padded outputs of a 64-slot pass cost ~1.5 ms per filter
#: update to allocate and fill at 2000 particles; the few poses that overflow are traced
#: again with room for all their paths.
FIRST_CAPACITY = 16


def _capacity(n_walls: int, max_order: int) -> int:
    """Slots per pose of the first pass: the number of wall sequences without repeats (an
    upper bound on the paths of one pose), capped at :data:`FIRST_CAPACITY`."""
    total = sum(n_walls * max(n_walls - 1, 0) ** (k - 1) for k in range(1, max_order + 1))
    return max(1, min(total, FIRST_CAPACITY))


def _empty_out(n: int, cap: int, max_order: int) -> _Out:
    return _Out(
        np.zeros(n, dtype=np.int64), np.full((n, cap), np.nan), np.full((n, cap), np.nan),
        np.full((n, cap), np.nan), np.zeros((n, cap), dtype=np.int64),
        np.full((n, cap, max_order), -1, dtype=np.int64),
        np.full((n, cap, max_order, 2), np.nan), np.full((n, cap), np.nan),
    )


#: No right corners: the kernel's exact image paths only.
_NO_CORNERS = _Corners(np.zeros((0, 2), dtype=np.int64), np.zeros((0, 2)), np.zeros((0, 2)),
                       np.zeros((0, 2)), np.zeros((0, 0), dtype=np.bool_))


def _kernel_corners(walls: WallSet, lim: _Limits, params: ForwardParams) -> _Corners:
    """The right corners heard at their vertex (none when ``right_corner_tol_deg`` is 0).

    Cached by the walls' coordinates and the two settings: a filter asks for the same walls
    several times per block (measured: 0.8 ms of a 15 ms update recomputing them)."""
    if params.right_corner_tol_deg <= 0 or walls.n < 2 or lim.max_order < 2:
        return _NO_CORNERS
    seg = np.ascontiguousarray(walls.segments_m, dtype=np.float64)
    return _corners_of(seg.tobytes(), seg.shape, float(params.right_corner_tol_deg),
                       float(params.corner_join_m))


@functools.lru_cache(maxsize=64)
def _corners_of(segments: bytes, shape: tuple[int, ...], tol_deg: float,
                join_m: float) -> _Corners:
    """:func:`_kernel_corners` of walls given as the bytes of their (W, 2, 2) coordinates
    (read-only arrays: the result is shared between calls)."""
    seg = np.frombuffer(segments, dtype=np.float64).reshape(shape)
    corners = right_corners(seg, tol_deg, join_m)
    if not corners:
        return _NO_CORNERS
    pairs, vertex, ea, eb = _corner_arrays(seg, corners)
    n = seg.shape[0]
    skip = np.zeros((n, n), dtype=np.bool_)
    skip[pairs[:, 0], pairs[:, 1]] = True
    skip[pairs[:, 1], pairs[:, 0]] = True
    for a in (pairs, vertex, ea, eb, skip):
        a.flags.writeable = False
    return _Corners(pairs, vertex, ea, eb, skip)


def _run(walls: WallSet, poses: FloatArray, lim: _Limits, params: ForwardParams,
         parallel: bool) -> _Out:
    n = poses.shape[0]
    cap = _capacity(walls.n, lim.max_order)
    corners = _kernel_corners(walls, lim, params)
    out = _traced(walls, poses, lim, corners, cap, parallel)
    over = np.flatnonzero(out.n_found > cap)
    if over.size == 0:
        return out
    # a pose that overflowed has no room for every path (nor for the repeat check of the
    # ones it missed): trace those poses again with room for all, then merge the rows
    most = int(out.n_found[over].max())
    again = _traced(walls, np.ascontiguousarray(poses[over]), lim, corners, most,
                    parallel and over.size >= 64)
    merged = _empty_out(n, most, lim.max_order)
    merged.n_found[:] = out.n_found
    for whole, first in zip(merged[1:], out[1:], strict=True):
        whole[:, :cap] = first
    for whole, redo in zip(merged, again, strict=True):
        whole[over] = redo
    return merged


def _traced(walls: WallSet, poses: FloatArray, lim: _Limits, corners: _Corners, cap: int,
            parallel: bool) -> _Out:
    """One pass of the kernel with ``cap`` slots per pose (``n_found`` may exceed it)."""
    out = _empty_out(poses.shape[0], cap, lim.max_order)
    if walls.n and poses.shape[0]:
        if not parallel:
            _serial_echoes(_kernel_walls(walls), lim, corners, poses, out)
        else:
            _batch_echoes(_kernel_walls(walls), lim, corners, poses, out)
    return out


def echoes(
    walls: WallSet,
    pose: ArrayLike,
    speed_m_s: float,
    config: SonarConfig,
    params: ForwardParams = DEFAULT_PARAMS,
) -> Echoes:
    """Specular echoes heard at the block centre from ``pose`` (the heat map's ``Run.pose``).

    Parameters
    ----------
    walls : WallSet
    pose : array_like, shape (3,)
        ``x, y`` in metres and the heading in radians (world frame).
    speed_m_s : float
        Signed odometry speed; the direction of travel is the heading for ``speed >= 0`` and
        heading + pi for ``speed < 0`` (as :func:`mapping.heatmap.doppler_heatmap`). At 0 the
        Doppler cosines are still given relative to the heading.
    config : SonarConfig
    params : ForwardParams

    Returns
    -------
    Echoes
        Sorted by range; only paths with one-way range <= ``max_range_m``.

    Raises
    ------
    ValueError
        Naming the parameter (walls, pose, speed_m_s, config, params).

    Notes
    -----
    Paths are the specular image-source paths of a monostatic sonar: the image of the
    sonar position S after reflections in walls w1..wk is the affine map ``I = A S + b``;
    the path exists when tracing back from S towards I meets the walls in turn on their
    finite segments and no leg crosses another wall. A zero-length leg (two bounces at one
    point) is accepted only in an inside corner (air-side angle < 180 deg); outside corners
    only diffract. Paths with the same map (e.g. (i, j) and (j, i) of a 90 deg corner) count
    once, as in the image-source engine.

    Doppler (derivation): with the sonar at ``S(t) = S_c + v (t - t_c)``, the delay of the
    echo heard at t solves ``c tau = |S(t) - A S(t - tau) - b|``; differentiating,
    ``tau' = u.(v - A v) / (c - u.A v)`` with u the unit vector from I to S. The arrival
    direction is -u, the departure direction ``A^T u``, so ``u.(v - A v) =
    -2 |v| (cos_dep + cos_arr) / 2``: eq. 1's row with ``cos theta = cos_doppler`` undoes it
    (to first order in v / c, ~3e-4). Retardation: the echo heard at t_c left at
    ``t_c - L / c``, so ``L = |D + A v L / c|`` with ``D = S_c - I_c``, solved exactly
    (a quadratic); for a wall ahead L = L0 (1 + v / c) to first order (mm level).
    """
    _check_walls(walls)
    lim = _limits(speed_m_s, config, params)
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f"pose must be 3 finite numbers (x, y, heading), got {pose!r}")
    batch = _to_batch(_run(walls, p[None].copy(), lim, params, parallel=False), params.spreading)
    return batch.echoes_of(0)


def echoes_batch(
    walls: WallSet,
    poses: ArrayLike,
    speed_m_s: float,
    config: SonarConfig,
    params: ForwardParams = DEFAULT_PARAMS,
    parallel: bool = True,
) -> EchoBatch:
    """Echoes of many poses in one call (numba, parallel over poses): see :func:`echoes`.

    Parameters
    ----------
    poses : array_like, shape (n, 3)
        ``x, y, heading`` of each pose (e.g. particles), all at the same speed.
    parallel : bool
        Spread the poses over numba's threads (False: one thread, for a few poses, where
        starting the parallel region costs more than the work; same results).

    Returns
    -------
    EchoBatch
        Padded arrays (n, kmax), ``kmax`` the largest count, each row sorted by range.
    """
    _check_walls(walls)
    lim = _limits(speed_m_s, config, params)
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise ValueError(f"poses must be finite with shape (n, 3), got shape {p.shape}")
    out = _run(walls, np.ascontiguousarray(p), lim, params, parallel=parallel)
    return _to_batch(out, params.spreading)


def _to_batch(out: _Out, spreading: str) -> EchoBatch:
    kmax = int(out.n_found.max()) if out.n_found.size else 0
    return EchoBatch(
        count=out.n_found,
        range_m=out.path_m[:, :kmax] / 2.0,
        cos_doppler=out.cos_doppler[:, :kmax],
        amplitude=out.amplitude[:, :kmax],
        order=out.order[:, :kmax],
        walls=out.walls[:, :kmax],
        points_m=out.points[:, :kmax],
        arrival_bearing_rad=out.bearing[:, :kmax],
        spreading=spreading,
    )
