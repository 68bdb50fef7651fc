"""numba kernels of :mod:`mapping.forward` (private; imported only by ``_echoes`` and ``_render``).

``_batch_echoes`` enumerates, for every pose, the specular image-source paths of a set of wall
segments up to an order and writes each valid one (range, Doppler cosine, amplitude, walls,
specular points, arrival bearing) into padded output arrays, hearing the right corners of
:class:`_Corners` once at their vertex instead of by their exact order-2 paths;
``_render_rows`` spreads a list of echoes over the heat-map grid with the drift-averaged
point-spread function. Inputs come as small namedtuples (:class:`_Walls`, :class:`_Limits`,
:class:`_Corners`, :class:`_Out`, :class:`_Psf`). The plain numpy twins live with the tests
(``tests/mapping/forward/naive.py``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from mapping.numba_config import NUMBA_FLAGS, PARALLEL

#: Tolerance on the wall parameter u in [0, 1] (a specular point on a wall end counts).
U_TOL = 1e-9
#: Leg parameter below which a leg has zero length (two bounces at one corner point).
S_TOL = 1e-9
#: Two image maps are the same path when every entry of (A, b) agrees to this.
MAP_TOL = 1e-7


class _Walls(NamedTuple):
    """Walls as the kernel sees them: end points, mirror maps x -> A x + b, strengths."""

    p0: np.ndarray  # (W, 2)
    d: np.ndarray  # (W, 2) p1 - p0
    A: np.ndarray  # (W, 2, 2)
    b: np.ndarray  # (W, 2)
    strength: np.ndarray  # (W,)


class _Limits(NamedTuple):
    """Scalars of one call: order, longest round trip, amplitude floor, physics constants."""

    max_order: int
    max_path_m: float
    min_amplitude: float
    sound_speed_m_s: float
    spreading_power: float
    speed_m_s: float


class _Corners(NamedTuple):
    """Right corners (m of them, m may be 0) heard at their vertex (``_corners``).

    ``pairs[c] = (i, j)`` (i < j) are the two walls, ``vertex[c]`` their shared end, ``ea``,
    ``eb`` the wedge edges (vertex -> far end of wall i, j); ``skip[i, j]`` (W, W; (0, 0)
    when m = 0) marks the order-2 wall sequences the vertex echo replaces, both ways.
    """

    pairs: np.ndarray  # (m, 2) int64
    vertex: np.ndarray  # (m, 2)
    ea: np.ndarray  # (m, 2)
    eb: np.ndarray  # (m, 2)
    skip: np.ndarray  # (W, W) bool


class _Out(NamedTuple):
    """Padded per-pose outputs (n poses, cap echoes); ``n_found`` may exceed cap (overflow)."""

    n_found: np.ndarray  # (n,) int64
    path_m: np.ndarray  # (n, cap) retarded round-trip length
    cos_doppler: np.ndarray  # (n, cap)
    amplitude: np.ndarray  # (n, cap)
    order: np.ndarray  # (n, cap) int64
    walls: np.ndarray  # (n, cap, K) int64
    points: np.ndarray  # (n, cap, K, 2)
    bearing: np.ndarray  # (n, cap)


class _Scratch(NamedTuple):
    """Work arrays of one thread, reused pose after pose (allocating them per pose cost
    about a sixth of the kernel). ``stamp[i, j]`` is the pose index for which the order-2
    wall pair (i, j) was traced (-1: not yet), ``valid2[i, j]`` its result and ``pts2[i, j]``
    its bounce points: the reversed pair is the same path walked backwards (a monostatic
    sonar), so it reuses them instead of tracing again."""

    mA: np.ndarray  # (kmax + 1, 2, 2)
    mb: np.ndarray  # (kmax + 1, 2)
    img: np.ndarray  # (kmax + 1, 2)
    seq: np.ndarray  # (kmax,) int64
    nxt: np.ndarray  # (kmax,) int64
    pts: np.ndarray  # (kmax, 2)
    keys: np.ndarray  # (cap, 6)
    stamp: np.ndarray  # (W, W) int64
    valid2: np.ndarray  # (W, W) bool
    pts2: np.ndarray  # (W, W, 2, 2)
    ts: np.ndarray  # (W,) the pose along each wall: (S - p0) . d
    hs: np.ndarray  # (W,) and off it: d x (S - p0)
    rank: np.ndarray  # (cap,) int64: a row's echoes in order of path length
    tmp_f: np.ndarray  # (cap, 4 + 2 kmax): a row's float fields while it is permuted
    tmp_i: np.ndarray  # (cap, 1 + kmax) int64: its integer fields


@numba.njit(**NUMBA_FLAGS)
def _scratch(n_walls: int, kmax: int, cap: int) -> _Scratch:
    return _Scratch(np.empty((kmax + 1, 2, 2)), np.empty((kmax + 1, 2)),
                    np.empty((kmax + 1, 2)), np.empty(kmax, dtype=np.int64),
                    np.empty(kmax, dtype=np.int64), np.empty((kmax, 2)), np.empty((cap, 6)),
                    np.full((n_walls, n_walls), -1, dtype=np.int64),
                    np.zeros((n_walls, n_walls), dtype=np.bool_),
                    np.empty((n_walls, n_walls, 2, 2)), np.empty(n_walls), np.empty(n_walls),
                    np.empty(cap, dtype=np.int64),
                    np.empty((cap, 4 + 2 * kmax)), np.empty((cap, 1 + kmax), dtype=np.int64))


@numba.njit(inline="always", **NUMBA_FLAGS)
def _cross(ax: float, ay: float, bx: float, by: float) -> float:
    return ax * by - ay * bx


@numba.njit(inline="always", **NUMBA_FLAGS)
def _corner_ok(walls: _Walls, a: int, b: int, cx: float, cy: float, px: float, py: float) -> bool:
    """Two bounces at one point C (walls a then b): valid only in an inside corner.

    The point ``p`` the ray comes from must lie strictly inside a convex wedge spanned by a
    ray of wall a and a ray of wall b from C (a wall through C in its interior offers both
    directions, a wall ending at C only the one along it). Outside (reflex) corners fail.
    """
    qx, qy = px - cx, py - cy
    for sa in range(2):
        ea = _ray_from(walls, a, cx, cy, sa)
        if ea[0] == 0.0 and ea[1] == 0.0:
            continue
        for sb in range(2):
            eb = _ray_from(walls, b, cx, cy, sb)
            if eb[0] == 0.0 and eb[1] == 0.0:
                continue
            k = _cross(ea[0], ea[1], eb[0], eb[1])
            if abs(k) < 1e-12:
                continue
            if (_cross(ea[0], ea[1], qx, qy) * k > 0.0
                    and _cross(qx, qy, eb[0], eb[1]) * k > 0.0):
                return True
    return False


@numba.njit(inline="always", **NUMBA_FLAGS)
def _ray_from(walls: _Walls, w: int, cx: float, cy: float, side: int) -> tuple[float, float]:
    """Direction along wall ``w`` from point C towards its end ``side`` (0: p0, 1: p1);
    (0, 0) when C is (within tolerance) that end itself."""
    ex = walls.p0[w, 0] + side * walls.d[w, 0] - cx
    ey = walls.p0[w, 1] + side * walls.d[w, 1] - cy
    length = math.hypot(walls.d[w, 0], walls.d[w, 1])
    if math.hypot(ex, ey) <= 1e-9 * max(length, 1.0):
        return 0.0, 0.0
    return ex, ey


@numba.njit(inline="always", **NUMBA_FLAGS)
def _blocked(walls: _Walls, ax: float, ay: float, bx: float, by: float, w1: int, w2: int,
             u_tol: float) -> bool:
    """Whether any wall other than w1, w2 crosses the open leg a -> b (within ``u_tol`` of
    its ends)."""
    rx, ry = bx - ax, by - ay
    for w in range(walls.p0.shape[0]):
        if w == w1 or w == w2:
            continue
        dx, dy = walls.d[w, 0], walls.d[w, 1]
        den = _cross(rx, ry, dx, dy)
        if abs(den) <= 1e-15:
            continue
        qx, qy = walls.p0[w, 0] - ax, walls.p0[w, 1] - ay
        # s = cross(q, d) / den and u = cross(q, r) / den, compared without dividing
        sd = _cross(qx, qy, dx, dy)
        ud = _cross(qx, qy, rx, ry)
        if den < 0.0:
            den, sd, ud = -den, -sd, -ud
        if (S_TOL * den < sd < (1.0 - S_TOL) * den
                and -u_tol * den <= ud <= (1.0 + u_tol) * den):
            return True
    return False


#: Margin of :func:`_misses_wall` beyond the trace's own tolerances (relative to the wall):
#: a sequence it drops is one the trace would refuse by far more than rounding.
MISS_MARGIN = 1e-7


@numba.njit(inline="always", **NUMBA_FLAGS)
def _misses_wall(walls: _Walls, w: int, ix: float, iy: float, ts: float, hs: float) -> bool:
    """Whether the last bounce, in wall w, of a path whose previous image is (ix, iy) cannot
    exist: the receiver S (``ts``, ``hs``: its coordinates along and off the wall, scaled by
    the wall's length) and that image lie on opposite sides of the wall's line, or the
    bounce point falls off the segment. The trace's own test (the ray from S to the next
    image must cross the segment), without composing the image; used to skip a sequence
    before the work, never to accept one."""
    dx, dy = walls.d[w, 0], walls.d[w, 1]
    l2 = dx * dx + dy * dy
    qx, qy = ix - walls.p0[w, 0], iy - walls.p0[w, 1]
    ti = qx * dx + qy * dy
    hi = dx * qy - dy * qx
    if hs * hi <= 0.0:
        tol = MISS_MARGIN * math.sqrt(l2)
        return abs(hs) > tol and abs(hi) > tol   # strictly on opposite sides
    t = ts + (ti - ts) * hs / (hs + hi)          # the bounce point along the wall
    margin = (U_TOL + MISS_MARGIN) * l2
    return t < -margin or t > l2 + margin


@numba.njit(inline="always", **NUMBA_FLAGS)
def _trace(walls: _Walls, seq: np.ndarray, k: int, img: np.ndarray, sx: float, sy: float,
           pts: np.ndarray) -> bool:
    """Specular points of the wall sequence ``seq[:k]`` (images ``img[0..k]``, img[0] = S);
    True when every point lies on its segment, no leg is blocked and zero-length legs are
    inside corners. Fills ``pts[:k]`` in the order the sound hits the walls."""
    px, py = sx, sy
    for m in range(k - 1, -1, -1):  # from the receiver back towards the source
        w = seq[m]
        tx, ty = img[m + 1, 0], img[m + 1, 1]
        rx, ry = tx - px, ty - py
        dx, dy = walls.d[w, 0], walls.d[w, 1]
        den = _cross(rx, ry, dx, dy)
        if abs(den) <= 1e-15:
            return False
        qx, qy = walls.p0[w, 0] - px, walls.p0[w, 1] - py
        s = _cross(qx, qy, dx, dy) / den
        u = _cross(qx, qy, rx, ry) / den
        low = S_TOL if m == k - 1 else -S_TOL
        if not (low < s < 1.0 - 1e-12 and -U_TOL <= u <= 1.0 + U_TOL):
            return False
        px, py = px + s * rx, py + s * ry
        pts[m, 0], pts[m, 1] = px, py
    # legs in sound order: S -> Q0 -> ... -> Q(k-1) -> S
    prev_zero = False
    for m in range(k + 1):
        ax, ay = (sx, sy) if m == 0 else (pts[m - 1, 0], pts[m - 1, 1])
        bx, by = (sx, sy) if m == k else (pts[m, 0], pts[m, 1])
        w1 = -1 if m == 0 else seq[m - 1]
        w2 = -1 if m == k else seq[m]
        if (bx - ax) ** 2 + (by - ay) ** 2 <= 1e-18:  # zero-length leg (no libm hypot)
            if m == 0 or m == k or prev_zero:
                return False
            ox, oy = (sx, sy) if m == 1 else (pts[m - 2, 0], pts[m - 2, 1])
            if not _corner_ok(walls, w1, w2, ax, ay, ox, oy):
                return False
            prev_zero = True
            continue
        prev_zero = False
        if _blocked(walls, ax, ay, bx, by, w1, w2, U_TOL):
            return False
        if k == 1:
            return True  # the way back is the same leg, with the same wall left out
    return True


@numba.njit(**NUMBA_FLAGS)
def _pose_echoes(walls: _Walls, lim: _Limits, corners: _Corners, pose: np.ndarray, out: _Out,
                 i: int, sc: _Scratch) -> None:
    """All valid paths of one pose into row ``i`` of ``out`` (sorted by length): the exact
    ones, less the order-2 paths of each right corner, then the corners' vertex echoes."""
    n_walls = walls.p0.shape[0]
    has_corners = corners.pairs.shape[0] > 0
    kmax = lim.max_order
    cap = out.path_m.shape[1]
    sx, sy, heading = pose[0], pose[1], pose[2]
    hx, hy = math.cos(heading), math.sin(heading)
    sign = -1.0 if lim.speed_m_s < 0.0 else 1.0
    tx, ty = sign * hx, sign * hy  # direction of travel
    vx, vy = lim.speed_m_s * hx, lim.speed_m_s * hy  # velocity
    c = lim.sound_speed_m_s
    mA, mb, img, seq, nxt, pts, keys = sc.mA, sc.mb, sc.img, sc.seq, sc.nxt, sc.pts, sc.keys
    mA[0, 0, 0], mA[0, 0, 1], mA[0, 1, 0], mA[0, 1, 1] = 1.0, 0.0, 0.0, 1.0
    mb[0] = 0.0
    img[0, 0], img[0, 1] = sx, sy
    for w in range(n_walls):
        qx, qy = sx - walls.p0[w, 0], sy - walls.p0[w, 1]
        sc.ts[w] = qx * walls.d[w, 0] + qy * walls.d[w, 1]
        sc.hs[w] = walls.d[w, 0] * qy - walls.d[w, 1] * qx
    count = 0
    for order in range(1, kmax + 1):
        depth = 0
        nxt[0] = 0
        while depth >= 0:
            w = nxt[depth]
            if w >= n_walls:
                depth -= 1
                continue
            nxt[depth] = w + 1
            if depth > 0 and w == seq[depth - 1]:
                continue
            if has_corners and order == 2 and depth == 1 and corners.skip[seq[0], w]:
                continue  # a right corner: heard at its vertex below
            seq[depth] = w
            if depth + 1 == order and _misses_wall(walls, w, img[depth, 0], img[depth, 1],
                                                   sc.ts[w], sc.hs[w]):
                if order == 2:   # the reversed pair, the same path backwards, fails too
                    sc.stamp[seq[0], w] = i
                    sc.valid2[seq[0], w] = False
                continue
            _compose(walls, w, mA, mb, depth)
            ix = mA[depth + 1, 0, 0] * sx + mA[depth + 1, 0, 1] * sy + mb[depth + 1, 0]
            iy = mA[depth + 1, 1, 0] * sx + mA[depth + 1, 1, 1] * sy + mb[depth + 1, 1]
            img[depth + 1, 0], img[depth + 1, 1] = ix, iy
            if (sx - ix) ** 2 + (sy - iy) ** 2 > lim.max_path_m**2:
                continue  # every path through this prefix is at least this long
            if depth + 1 < order:
                depth += 1
                nxt[depth] = 0
                continue
            if order == 2 and sc.stamp[seq[1], seq[0]] == i:
                # the reversed pair was traced for this pose: the same path backwards
                if not sc.valid2[seq[1], seq[0]]:
                    continue
                pts[0, 0], pts[0, 1] = sc.pts2[seq[1], seq[0], 1, 0], sc.pts2[seq[1], seq[0], 1, 1]
                pts[1, 0], pts[1, 1] = sc.pts2[seq[1], seq[0], 0, 0], sc.pts2[seq[1], seq[0], 0, 1]
            else:
                ok = _trace(walls, seq, order, img, sx, sy, pts)
                if order == 2:
                    sc.stamp[seq[0], seq[1]] = i
                    sc.valid2[seq[0], seq[1]] = ok
                    if ok:
                        for m in range(2):
                            sc.pts2[seq[0], seq[1], m, 0] = pts[m, 0]
                            sc.pts2[seq[0], seq[1], m, 1] = pts[m, 1]
                if not ok:
                    continue
            if _seen(mA[order], mb[order], keys, min(count, cap)):
                continue
            # geometry of the unfolded path: image -> receiver
            dx, dy = sx - ix, sy - iy
            length0 = math.sqrt(dx * dx + dy * dy)
            if length0 <= 1e-6:
                continue
            ux, uy = dx / length0, dy / length0
            ax = (mA[order, 0, 0] * vx + mA[order, 0, 1] * vy) / c
            ay = (mA[order, 1, 0] * vx + mA[order, 1, 1] * vy) / c
            # retarded length: |D + a L| = L (emitted L / c before the block centre)
            da = dx * ax + dy * ay
            aa = ax * ax + ay * ay
            length = (da + math.sqrt(da * da + (1.0 - aa) * length0 * length0)) / (1.0 - aa)
            if length > lim.max_path_m:
                continue
            gain = 1.0
            for m in range(order):
                gain *= walls.strength[seq[m]]
            amp = gain / _spread(length, lim.spreading_power)
            if abs(amp) < lim.min_amplitude:
                continue
            cos_dep = ux * (mA[order, 0, 0] * tx + mA[order, 0, 1] * ty) + uy * (
                mA[order, 1, 0] * tx + mA[order, 1, 1] * ty)
            cos_arr = -(ux * tx + uy * ty)
            if count < cap:
                keys[count, 0] = mA[order, 0, 0]
                keys[count, 1] = mA[order, 0, 1]
                keys[count, 2] = mA[order, 1, 0]
                keys[count, 3] = mA[order, 1, 1]
                keys[count, 4] = mb[order, 0]
                keys[count, 5] = mb[order, 1]
                out.path_m[i, count] = length
                out.cos_doppler[i, count] = 0.5 * (cos_dep + cos_arr)
                out.amplitude[i, count] = amp
                out.order[i, count] = order
                for m in range(kmax):
                    out.walls[i, count, m] = seq[m] if m < order else -1
                    out.points[i, count, m, 0] = pts[m, 0] if m < order else np.nan
                    out.points[i, count, m, 1] = pts[m, 1] if m < order else np.nan
                out.bearing[i, count] = math.atan2(pts[order - 1, 1] - sy, pts[order - 1, 0] - sx)
            count += 1
    for m in range(corners.pairs.shape[0]):
        if _vertex_echo(walls, lim, corners, m, sx, sy, tx, ty, vx, vy, out, i, count):
            count += 1
    out.n_found[i] = count
    _sort_row(out, i, min(count, cap), sc)


@numba.njit(**NUMBA_FLAGS)
def _vertex_echo(walls: _Walls, lim: _Limits, corners: _Corners, m: int, sx: float, sy: float,
                 tx: float, ty: float, vx: float, vy: float, out: _Out, i: int,
                 slot: int) -> bool:
    """The retro-reflection of right corner m heard from S, written to ``out[i, slot]`` when
    there is room: True when heard (S strictly inside the corner's convex wedge, the line of
    sight to the vertex clear, within the path and amplitude limits).

    The image of S in both walls is its point reflection through the vertex C, so the round
    trip is retarded as the exact paths are: ``L = |D + a L|`` with ``D = 2 (S - C)`` and
    ``a = -v / c`` (the map's A = -I); amplitude ``s_i s_j / L**p``; Doppler cosine of the
    direction to C (departure = arrival); both bounce points at C.
    """
    cx, cy = corners.vertex[m, 0], corners.vertex[m, 1]
    ex, ey = corners.ea[m, 0], corners.ea[m, 1]
    fx, fy = corners.eb[m, 0], corners.eb[m, 1]
    k = _cross(ex, ey, fx, fy)
    if abs(k) < 1e-9:
        return False
    qx, qy = sx - cx, sy - cy
    if not (_cross(ex, ey, qx, qy) * k > 0.0 and _cross(qx, qy, fx, fy) * k > 0.0):
        return False
    wi, wj = corners.pairs[m, 0], corners.pairs[m, 1]
    if _blocked(walls, sx, sy, cx, cy, wi, wj, 0.0):
        return False
    dist = math.hypot(qx, qy)
    if dist <= 1e-6:
        return False
    c = lim.sound_speed_m_s
    ax, ay = -vx / c, -vy / c
    da = 2.0 * (qx * ax + qy * ay)
    aa = ax * ax + ay * ay
    length0 = 2.0 * dist
    length = (da + math.sqrt(da * da + (1.0 - aa) * length0 * length0)) / (1.0 - aa)
    if length > lim.max_path_m:
        return False
    amp = walls.strength[wi] * walls.strength[wj] / _spread(length, lim.spreading_power)
    if abs(amp) < lim.min_amplitude:
        return False
    if slot < out.path_m.shape[1]:
        out.path_m[i, slot] = length
        out.cos_doppler[i, slot] = -(qx * tx + qy * ty) / dist
        out.amplitude[i, slot] = amp
        out.order[i, slot] = 2
        for r in range(out.walls.shape[2]):
            out.walls[i, slot, r] = wi if r == 0 else (wj if r == 1 else -1)
            out.points[i, slot, r, 0] = cx if r < 2 else np.nan
            out.points[i, slot, r, 1] = cy if r < 2 else np.nan
        out.bearing[i, slot] = math.atan2(-qy, -qx)
    return True


@numba.njit(inline="always", **NUMBA_FLAGS)
def _spread(length: float, power: float) -> float:
    """``length**power``, the spreading loss; the 3-D power 1 without ``pow`` (the same
    number: ``pow(x, 1) == x``; ``pow`` cost about 3 % of the kernel)."""
    return length if power == 1.0 else length**power


@numba.njit(inline="always", **NUMBA_FLAGS)
def _compose(walls: _Walls, w: int, mA: np.ndarray, mb: np.ndarray, depth: int) -> None:
    """Map after one more reflection in wall w: (A, b) -> (M A, M b + m)."""
    M = walls.A[w]
    for r in range(2):
        for col in range(2):
            mA[depth + 1, r, col] = M[r, 0] * mA[depth, 0, col] + M[r, 1] * mA[depth, 1, col]
        mb[depth + 1, r] = M[r, 0] * mb[depth, 0] + M[r, 1] * mb[depth, 1] + walls.b[w, r]


@numba.njit(inline="always", **NUMBA_FLAGS)
def _seen(A: np.ndarray, b: np.ndarray, keys: np.ndarray, n: int) -> bool:
    """Whether the map (A, b) is already among the first n accepted maps (same image)."""
    for j in range(n):
        if (abs(keys[j, 0] - A[0, 0]) < MAP_TOL and abs(keys[j, 1] - A[0, 1]) < MAP_TOL
                and abs(keys[j, 2] - A[1, 0]) < MAP_TOL and abs(keys[j, 3] - A[1, 1]) < MAP_TOL
                and abs(keys[j, 4] - b[0]) < MAP_TOL and abs(keys[j, 5] - b[1]) < MAP_TOL):
            return True
    return False


@numba.njit(**NUMBA_FLAGS)
def _sort_row(out: _Out, i: int, n: int, sc: _Scratch) -> None:
    """Order the first n echoes of row i by path length (stable): an insertion sort of their
    indices, then one permutation of the fields (moving every field at each swap of the
    sort cost about 8 % of the kernel)."""
    rank = sc.rank
    for a in range(n):
        rank[a] = a
    moved = False
    for a in range(1, n):
        j = a
        while j > 0 and out.path_m[i, rank[j - 1]] > out.path_m[i, rank[j]]:
            rank[j - 1], rank[j] = rank[j], rank[j - 1]
            j -= 1
            moved = True
    if not moved:
        return
    kmax = out.walls.shape[2]
    tf, ti = sc.tmp_f, sc.tmp_i
    for a in range(n):
        tf[a, 0] = out.path_m[i, a]
        tf[a, 1] = out.cos_doppler[i, a]
        tf[a, 2] = out.amplitude[i, a]
        tf[a, 3] = out.bearing[i, a]
        ti[a, 0] = out.order[i, a]
        for m in range(kmax):
            ti[a, 1 + m] = out.walls[i, a, m]
            tf[a, 4 + 2 * m] = out.points[i, a, m, 0]
            tf[a, 5 + 2 * m] = out.points[i, a, m, 1]
    for a in range(n):
        r = rank[a]
        out.path_m[i, a] = tf[r, 0]
        out.cos_doppler[i, a] = tf[r, 1]
        out.amplitude[i, a] = tf[r, 2]
        out.bearing[i, a] = tf[r, 3]
        out.order[i, a] = ti[r, 0]
        for m in range(kmax):
            out.walls[i, a, m] = ti[r, 1 + m]
            out.points[i, a, m, 0] = tf[r, 4 + 2 * m]
            out.points[i, a, m, 1] = tf[r, 5 + 2 * m]


#: Poses per work item of the parallel loop (each item allocates its scratch once).
CHUNK = 32


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _batch_echoes(walls: _Walls, lim: _Limits, corners: _Corners, poses: np.ndarray,
                  out: _Out) -> None:
    """Echoes of every pose (parallel over chunks of poses); see :func:`_pose_echoes`."""
    n = poses.shape[0]
    cap = out.path_m.shape[1]
    for c in numba.prange((n + CHUNK - 1) // CHUNK):
        sc = _scratch(walls.p0.shape[0], lim.max_order, cap)
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            _pose_echoes(walls, lim, corners, poses[i], out, i, sc)


@numba.njit(**NUMBA_FLAGS)
def _serial_echoes(walls: _Walls, lim: _Limits, corners: _Corners, poses: np.ndarray,
                   out: _Out) -> None:
    """Echoes of every pose, serially (no thread start-up: one pose, or the few poses of a
    finite-difference Jacobian, where starting a parallel region costs more than the work)."""
    sc = _scratch(walls.p0.shape[0], lim.max_order, out.path_m.shape[1])
    for i in range(poses.shape[0]):
        _pose_echoes(walls, lim, corners, poses[i], out, i, sc)


# ---- rendering ------------------------------------------------------------------------------
class _Psf(NamedTuple):
    """Point-spread tables on a grid ``up`` times finer than the lag samples (one period).

    ``corr`` is the analytic circular correlation C(x) of the heard period with the
    transmitted one (peak ~1), ``prim`` its periodic primitive G(x) (so that
    ``int_a^b C = mean * (b - a) + G(b) - G(a)``), ``mean`` the mean of C (its DC term).
    """

    corr_re: np.ndarray
    corr_im: np.ndarray
    prim_re: np.ndarray
    prim_im: np.ndarray
    mean_re: float
    mean_im: float
    up: int


@numba.njit(**NUMBA_FLAGS)
def _lagrange(table: np.ndarray, u: float) -> float:
    """4-point cubic Lagrange interpolation of a periodic table at fine position u."""
    n = table.size
    fl = math.floor(u)
    f = u - fl
    i = int(fl) % n
    ym1 = table[(i - 1) % n]
    y0 = table[i]
    y1 = table[(i + 1) % n]
    y2 = table[(i + 2) % n]
    return (-f * (f - 1.0) * (f - 2.0) / 6.0 * ym1 + (f + 1.0) * (f - 1.0) * (f - 2.0) / 2.0 * y0
            - (f + 1.0) * f * (f - 2.0) / 2.0 * y1 + (f + 1.0) * f * (f - 1.0) / 6.0 * y2)


@numba.njit(**NUMBA_FLAGS)
def _psf_at(psf: _Psf, x: float, drift: float) -> complex:
    """Drift-averaged correlation ``(1/D) int_{-D/2}^{D/2} C(x + d) dd`` (C(x) when D ~ 0)."""
    up = psf.up
    if abs(drift) < 1e-3:
        return complex(_lagrange(psf.corr_re, x * up), _lagrange(psf.corr_im, x * up))
    hi = (x + 0.5 * drift) * up
    lo = (x - 0.5 * drift) * up
    re = psf.mean_re * drift + _lagrange(psf.prim_re, hi) - _lagrange(psf.prim_re, lo)
    im = psf.mean_im * drift + _lagrange(psf.prim_im, hi) - _lagrange(psf.prim_im, lo)
    return complex(re / drift, im / drift)


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _render_rows(psf: _Psf, drift: np.ndarray, lag: np.ndarray, amp: np.ndarray,
                 half_width: float, coherent: bool, out: np.ndarray) -> None:
    """Heat map rows: ``out[n, j] = |sum_k amp_k h(j - lag_k, drift[n, k])|`` (coherent) or
    ``sqrt(sum_k |amp_k h|^2)`` (incoherent), each echo over ``|j - lag_k| <= |D|/2 +
    half_width`` (circular in j)."""
    n_rows, period = out.shape
    for n in numba.prange(n_rows):
        acc_re = np.zeros(period)
        acc_im = np.zeros(period)
        for k in range(lag.size):
            d = drift[n, k]
            reach = 0.5 * abs(d) + half_width
            j0 = int(math.ceil(lag[k] - reach))
            j1 = int(math.floor(lag[k] + reach))
            if j1 - j0 >= period:
                j1 = j0 + period - 1
            for j in range(j0, j1 + 1):
                v = amp[k] * _psf_at(psf, j - lag[k], d)
                jj = j % period
                if coherent:
                    acc_re[jj] += v.real
                    acc_im[jj] += v.imag
                else:
                    acc_re[jj] += v.real * v.real + v.imag * v.imag
        for j in range(period):
            if coherent:
                out[n, j] = math.hypot(acc_re[j], acc_im[j])
            else:
                out[n, j] = math.sqrt(acc_re[j])
