"""Tracing image paths on the finite wall segments (step 2 of :mod:`mapping.simulate.images`).

:func:`trace_images` decides, for each candidate image and robot position, whether the
specular path exists on the *finite* segments and is not blocked by another wall, walking
from the receiver towards the image and reflecting the target at the first wall met; the
wall sequence is reported in the order the sound hits the walls.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mapping.simulate.ism._images import ImageSet, _check_segments, mirror_maps

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

#: Tolerance on the wall parameter u in [0, 1] (a path through a wall end or a corner counts).
_U_TOL = 1e-9
#: Tolerance (metres) for "the traced target is the source itself".
_SOURCE_TOL_M = 1e-6


@dataclass(frozen=True)
class TraceResult:
    """Validity of image paths at robot positions (see :func:`trace_images`).

    Attributes
    ----------
    valid : ndarray of bool, shape (n, m)
        The specular path exists on the segments and no other wall blocks any leg.
    order : ndarray of int, shape (n, m)
        Number of reflections of the traced path (0 where invalid).
    walls : ndarray of int, shape (n, m, max_order)
        Wall ids in the order the sound hits them (-1 padding).
    reflection : ndarray, shape (n, m)
        Product of the reflection coefficients along the path (0 where invalid).
    path_length_m : ndarray, shape (n, m)
        Static path length |x - image| in metres.
    """

    valid: BoolArray
    order: IntArray
    walls: IntArray
    reflection: FloatArray
    path_length_m: FloatArray


def trace_images(
    images: ImageSet,
    segments: FloatArray,
    reflection: FloatArray,
    positions_m: FloatArray,
) -> TraceResult:
    """Validity and occlusion of every image path at every robot position.

    Parameters
    ----------
    images : ImageSet
    segments : ndarray, shape (W, 2, 2)
    reflection : ndarray, shape (W,)
        Reflection coefficient of each wall.
    positions_m : ndarray, shape (m, 2)
        Robot (source = receiver) positions.

    Returns
    -------
    TraceResult
        Arrays of shape (n_images, m).

    Notes
    -----
    From the receiver, the line towards the image must meet a wall first; the target is then
    reflected in that wall and the trace continues from the hit point, excluding the wall
    just left. A path is valid when, after its reflections, the target is the source and
    the last leg meets no wall; a leg that reaches the source while reflections remain, or
    a leg towards a virtual target that meets no wall, means no specular path. The trace
    meets the walls last-hit first, so ``walls`` is reversed at the end into the order the
    sound hits them (the first entry is the wall of the first reflection).
    """
    seg = _check_segments(segments)
    R = np.asarray(reflection, dtype=np.float64)
    if R.shape != (seg.shape[0],):
        raise ValueError(f"reflection must have shape ({seg.shape[0]},), got {R.shape}")
    pos = np.asarray(positions_m, dtype=np.float64).reshape(-1, 2)
    n, m = images.n, pos.shape[0]
    max_order = max(int(images.max_order), 1)
    WA, Wb = mirror_maps(seg)
    img = images.positions(pos)  # (n, m, 2)
    src = np.broadcast_to(pos[None], (n, m, 2)).reshape(-1, 2)
    P = src.copy()
    Q = src.copy()  # where each trace's current leg came from (for the corner rule)
    T = img.reshape(-1, 2).copy()
    N = P.shape[0]
    last = np.full(N, -1, dtype=np.int64)
    last_zero = np.zeros(N, dtype=bool)
    active = np.ones(N, dtype=bool)
    valid = np.zeros(N, dtype=bool)
    order = np.zeros(N, dtype=np.int64)
    walls = np.full((N, max_order), -1, dtype=np.int64)
    rprod = np.ones(N)
    c0, dseg = seg[:, 0], seg[:, 1] - seg[:, 0]
    for _step in range(max_order + 1):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        p, t = P[idx], T[idx]
        at_source = np.linalg.norm(t - src[idx], axis=1) < _SOURCE_TOL_M
        # a corner is two bounces at one point: at most one zero-length leg in a row, and
        # only in an inside corner (an outside corner has no specular path, issue 15)
        s, w = _first_hit(p, t, c0, dseg, last[idx], ~at_source & ~last_zero[idx])
        zero = (w >= 0) & (s <= 1e-9)
        if zero.any():
            bad = np.flatnonzero(zero)[~inside_corner(Q[idx][zero], p[zero], last[idx][zero],
                                                      w[zero], seg)]
            if bad.size:
                s[bad], w[bad] = _first_hit(p[bad], t[bad], c0, dseg, last[idx][bad],
                                            np.zeros(bad.size, dtype=bool))
        hit = w >= 0
        done_ok = at_source & ~hit
        valid[idx[done_ok]] = True
        # finished (valid, occluded, or no wall towards a virtual target)
        stop = done_ok | (at_source & hit) | (~at_source & ~hit)
        active[idx[stop]] = False
        go = idx[~stop]
        if go.size == 0:
            break
        wg = w[~stop]
        k = order[go]
        too_many = k >= max_order
        active[go[too_many]] = False
        go, wg, k = go[~too_many], wg[~too_many], k[~too_many]
        sg = s[~stop][~too_many]
        Q[go] = P[go]
        P[go] = P[go] + sg[:, None] * (T[go] - P[go])
        T[go] = (WA[wg] @ T[go][:, :, None])[:, :, 0] + Wb[wg]
        walls[go, k] = wg
        order[go] = k + 1
        rprod[go] *= R[wg]
        last[go] = wg
        last_zero[go] = sg <= 1e-9
    shape = (n, m)
    length = np.linalg.norm(img - pos[None], axis=2)
    valid = valid.reshape(shape) & (length > _SOURCE_TOL_M)
    sound = _sound_order(walls, order).reshape(n, m, max_order)
    valid &= ~repeated_paths(img, sound, valid)
    return TraceResult(
        valid=valid,
        order=np.where(valid, order.reshape(shape), 0),
        walls=np.where(valid[..., None], sound, -1),
        reflection=np.where(valid, rprod.reshape(shape), 0.0),
        path_length_m=length,
    )


#: Image points closer than this (metres) are one point when deduplicating paths.
_SAME_POINT_M = 1e-9


def repeated_paths(images_m: FloatArray, walls: IntArray, valid: BoolArray) -> BoolArray:
    """Valid paths that repeat an earlier image's physical path at the same robot position.

    Two distinct image maps can send the robot to the same point (in the L-room on the line
    x = 3, ``x - 6 = -x``); the trace depends only on the robot and the image point, so both
    trace the one physical path (same image point, same walls, same bounce points) and it
    would be heard twice (issue 15). The first image (lowest index) keeps it.

    Parameters
    ----------
    images_m : ndarray, shape (n, m, 2)
        Image points per image and robot position.
    walls : ndarray of int, shape (n, m, K)
        Traced wall sequences (-1 padded).
    valid : ndarray of bool, shape (n, m)

    Returns
    -------
    ndarray of bool, shape (n, m)
        True where a valid path is a repeat of a lower-index one.
    """
    i, j = np.nonzero(valid)
    out = np.zeros(valid.shape, dtype=bool)
    if i.size < 2:
        return out
    point = np.round(images_m[i, j] / _SAME_POINT_M).astype(np.int64)
    key = np.column_stack([j, point, walls[i, j]])
    order = np.lexsort((i,) + tuple(key.T[::-1]))  # by key, then by image index
    k = key[order]
    repeat = np.zeros(order.size, dtype=bool)
    repeat[1:] = np.all(k[1:] == k[:-1], axis=1)
    out[i[order[repeat]], j[order[repeat]]] = True
    return out


def _sound_order(walls: IntArray, order: IntArray) -> IntArray:
    """Each row's first ``order`` wall ids reversed, -1 after them.

    :func:`trace_images` walks from the receiver back to the source, so it records the
    walls last-hit first; this turns rows ``(w_k, ..., w_1, -1, ...)`` of shape (N, K) into
    the order the sound hits them, ``(w_1, ..., w_k, -1, ...)``.
    """
    j = np.arange(walls.shape[1])[None, :]
    src = order[:, None] - 1 - j
    picked = np.take_along_axis(walls, np.clip(src, 0, None), axis=1)
    return np.where(src >= 0, picked, -1).astype(np.int64)


def _first_hit(
    p: FloatArray,
    t: FloatArray,
    c0: FloatArray,
    dseg: FloatArray,
    exclude: IntArray,
    allow_zero: BoolArray,
) -> tuple[FloatArray, IntArray]:
    """Nearest wall met by each leg ``p -> t`` (leg parameter s in (0, 1)), excluding one wall.

    A wall through the start point itself (s ~ 0: the leg starts in a corner) counts only
    where ``allow_zero``: it is the second bounce of a corner path, but it never blocks the
    last leg back to the source.

    Returns the leg parameter and the wall id (-1 and inf when no wall is met).
    """
    r = t - p  # (N, 2)
    denom = r[:, None, 0] * dseg[None, :, 1] - r[:, None, 1] * dseg[None, :, 0]  # (N, W)
    q = c0[None] - p[:, None]  # (N, W, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (q[..., 0] * dseg[None, :, 1] - q[..., 1] * dseg[None, :, 0]) / denom
        u = (q[..., 0] * r[:, None, 1] - q[..., 1] * r[:, None, 0]) / denom
    ok = (
        (np.abs(denom) > 1e-15)
        & ((s > 1e-9) | (allow_zero[:, None] & (s > -1e-9)))
        & (s < 1.0 - 1e-12)
        & (u >= -_U_TOL)
        & (u <= 1.0 + _U_TOL)
    )
    ok &= np.arange(dseg.shape[0])[None, :] != exclude[:, None]
    s = np.where(ok, s, np.inf)
    w = np.argmin(s, axis=1)
    best = s[np.arange(s.shape[0]), w]
    return best, np.where(np.isfinite(best), w, -1).astype(np.int64)


def inside_corner(came_from: FloatArray, corner: FloatArray, wall_a: IntArray,
                  wall_b: IntArray, segments: FloatArray) -> BoolArray:
    """Whether each two-bounces-at-one-point path is in an inside corner.

    The ray arrives at the corner C (on walls a and b) from ``came_from``; geometric acoustics
    gives it a specular continuation only if that point lies strictly inside a convex wedge
    spanned by a ray of wall a and a ray of wall b from C (a wall through C in its interior
    offers both directions, a wall ending at C only the one along it). An outside (reflex,
    air-side angle > 180 deg) corner has no such wedge on the air side: it only diffracts.
    """
    q = came_from - corner
    out = np.zeros(corner.shape[0], dtype=bool)
    for ea in _rays(segments, wall_a, corner):
        for eb in _rays(segments, wall_b, corner):
            k = ea[:, 0] * eb[:, 1] - ea[:, 1] * eb[:, 0]
            c1 = (ea[:, 0] * q[:, 1] - ea[:, 1] * q[:, 0]) * k
            c2 = (q[:, 0] * eb[:, 1] - q[:, 1] * eb[:, 0]) * k
            out |= (np.abs(k) > 1e-12) & (c1 > 0) & (c2 > 0)
    return out


def _rays(segments: FloatArray, wall: IntArray, corner: FloatArray) -> list[FloatArray]:
    """Directions from each corner towards both ends of its wall ((0, 0) where the corner is
    that end)."""
    out = []
    for end in (0, 1):
        e = segments[wall, end] - corner
        short = np.hypot(e[:, 0], e[:, 1]) <= 1e-9 * np.maximum(
            np.hypot(*(segments[wall, 1] - segments[wall, 0]).T), 1.0)
        out.append(np.where(short[:, None], 0.0, e))
    return out
