"""Image-source geometry for 2-D scenes of wall segments (co-located source and receiver).

An image source is an affine map ``x -> A x + b`` (a composition of mirror reflections in
wall lines) applied to the robot position: the robot transmits at ``x`` and hears, among its
echoes, the wave that appears to come from ``A x + b``. Because source and receiver are the
same moving point, the image moves with the robot, mirrored through the walls in order.

Two steps, both pure functions over arrays:

1. :func:`candidate_images` enumerates the distinct maps up to an order, pruned by distance
   (a valid path is never shorter than the distance from the robot to the image of any of
   its prefixes, so a prefix farther than ``max_path_m`` from every robot position ends a
   branch) and by visibility (a child through wall ``w`` of an image reached through wall
   ``v`` is possible only if some ray from that image through segment ``v`` meets ``w``).
2. :func:`~mapping.simulate.images_trace.trace_images` (module
   :mod:`mapping.simulate.images_trace`) decides, for each candidate and robot position,
   whether the specular path exists on the *finite* segments and is not blocked by another
   wall: it traces the straight line from the receiver towards the image, reflects the
   target at the first wall that line meets, and repeats until the target is the source
   itself (valid) or the line runs out without a wall (no such path) or the source is
   reached too early (occluded).
   Tracing finds the wall sequence of the physical path, so the order, the walls and the
   product of the reflection coefficients come from the geometry, not from the enumeration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]



@dataclass(frozen=True)
class ImageSet:
    """Distinct image-source maps ``x -> A x + b``.

    Attributes
    ----------
    A : ndarray, shape (n, 2, 2)
        Linear parts (orthogonal, determinant (-1)**order).
    b : ndarray, shape (n, 2)
        Offsets in metres.
    order : ndarray of int, shape (n,)
        Number of reflections of the first wall sequence that produced the map.
    walls : tuple of tuple of int
        That wall sequence (first wall hit first), for reference; the traced path decides.
    max_order : int
        Highest order enumerated.
    truncated : bool
        True when enumeration stopped early at the image cap (see :func:`candidate_images`).
    """

    A: FloatArray
    b: FloatArray
    order: IntArray
    walls: tuple[tuple[int, ...], ...]
    max_order: int
    truncated: bool = False

    @property
    def n(self) -> int:
        """Number of images."""
        return int(self.order.size)

    def positions(self, xy: FloatArray) -> FloatArray:
        """Image positions for robot positions ``xy`` (m, 2) -> (n, m, 2)."""
        return _apply(self.A, self.b, np.asarray(xy, dtype=np.float64))


def _apply(A: FloatArray, b: FloatArray, xy: FloatArray) -> FloatArray:
    """Images ``A[n] x[m] + b[n]`` of points ``xy`` (m, 2) under maps (n, ...) -> (n, m, 2)."""
    return np.asarray(xy[None] @ A.transpose(0, 2, 1) + b[:, None, :])


def mirror_maps(segments: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mirror reflection ``x -> A x + b`` in the line through each wall segment.

    Parameters
    ----------
    segments : ndarray, shape (W, 2, 2)
        Wall end points ``[[x0, y0], [x1, y1]]`` in metres.

    Returns
    -------
    A : ndarray, shape (W, 2, 2)
        ``I - 2 n n^T`` with ``n`` the unit normal.
    b : ndarray, shape (W, 2)
        ``2 (p0 . n) n``.
    """
    seg = _check_segments(segments)
    d = seg[:, 1] - seg[:, 0]
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.linalg.norm(d, axis=1)[:, None]
    A = np.eye(2)[None] - 2.0 * n[:, :, None] * n[:, None, :]
    b = 2.0 * np.sum(seg[:, 0] * n, axis=1)[:, None] * n
    return A, b


def _check_segments(segments: FloatArray) -> FloatArray:
    seg = np.asarray(segments, dtype=np.float64)
    if seg.ndim != 3 or seg.shape[1:] != (2, 2):
        raise ValueError(f"segments must have shape (W, 2, 2), got {seg.shape}")
    if not np.all(np.isfinite(seg)):
        raise ValueError("segments must be finite")
    if np.any(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1) <= 0):
        raise ValueError("segments must have non-zero length")
    return seg


#: An aperture narrower than this (metres) is a point: a corner bounce, not followed further.
_POINT_APERTURE_M = 1e-7
_IDENTITY_KEY = (1.0, 0.0, 0.0, 1.0, 0.0, 0.0)


def _map_key(A: FloatArray, b: FloatArray) -> tuple[float, ...]:
    return tuple(np.round(np.concatenate([A.ravel(), b]), 7).tolist())


def candidate_images(
    segments: FloatArray,
    positions_m: FloatArray,
    max_order: int,
    max_path_m: float = np.inf,
    max_images: int = 20_000,
    truncate: bool = False,
) -> ImageSet:
    """Distinct image maps up to ``max_order`` that can matter for the given robot positions.

    Beam tracing without occlusion: every wall sequence carries, for each robot position,
    the part of its last wall that rays from its image can reach through the earlier walls
    (the aperture). A child through wall ``w`` keeps the positions where ``w`` meets the
    wedge from the image through that aperture, beyond it, and where the image is within
    ``max_path_m`` (a valid path is never shorter than the distance from the robot to the
    image of any of its prefixes); a sequence with no position left ends its branch. Exact
    validity and occlusion are decided later by :func:`trace_images`.

    Parameters
    ----------
    segments : ndarray, shape (W, 2, 2)
        Wall segments in metres.
    positions_m : ndarray, shape (m, 2)
        Robot positions the images will be used at (a sampling of the trajectory).
    max_order : int
        Highest number of reflections, >= 1.
    max_path_m : float
        Longest path of interest in metres.
    max_images : int
        Raise ``ValueError`` rather than enumerate more images (or follow more than 5
        times as many beams) than this ...
    truncate : bool
        ... or, if True, stop and return the images of the orders completed so far
        (``ImageSet.truncated`` is then True).

    Returns
    -------
    ImageSet
        ``max_order`` is the highest order that still produced a candidate.
    """
    seg = _check_segments(segments)
    if max_order < 1:
        raise ValueError(f"max_order must be >= 1, got {max_order}")
    if not max_path_m > 0:
        raise ValueError(f"max_path_m must be > 0, got {max_path_m}")
    pos = np.asarray(positions_m, dtype=np.float64).reshape(-1, 2)
    m = pos.shape[0]
    WA, Wb = mirror_maps(seg)
    lengths = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
    seen: set[tuple[float, ...]] = set()
    out_A: list[FloatArray] = []
    out_b: list[FloatArray] = []
    out_order: list[int] = []
    out_walls: list[tuple[int, ...]] = []
    # the frontier, as arrays over nodes: map, last wall, alive positions, apertures
    A = np.eye(2)[None]
    b = np.zeros((1, 2))
    last = np.array([-1])
    walls: list[tuple[int, ...]] = [()]
    alive = np.ones((1, m), dtype=bool)
    ap0 = ap1 = np.zeros((1, m, 2))
    reached = 0
    for order in range(1, max_order + 1):
        source = _apply(A, b, pos)  # parent images
        kids: list[tuple[FloatArray, ...]] = []
        kid_walls: list[tuple[int, ...]] = []
        for w in range(seg.shape[0]):
            A2 = WA[w] @ A
            b2 = b @ WA[w].T + Wb[w]
            img = _apply(A2, b2, pos)
            keep = alive & (last != w)[:, None]
            keep &= np.linalg.norm(img - pos[None], axis=2) <= max_path_m
            if order == 1:
                lo, hi = np.zeros((1, m)), np.ones((1, m))
            else:
                lo, hi, ok = _clip_beam(source, ap0, ap1, seg[w])
                keep &= ok
            identity = np.all(np.abs(A2 - np.eye(2)) < 1e-7, axis=(1, 2)) & np.all(
                np.abs(b2) < 1e-7, axis=1
            )
            keep &= ~identity[:, None]  # the robot itself: the direct path is not an echo
            hit = np.flatnonzero(np.any(keep, axis=1))
            for i in hit:
                key = _map_key(A2[i], b2[i])
                if key not in seen:
                    seen.add(key)
                    out_A.append(A2[i])
                    out_b.append(b2[i])
                    out_order.append(order)
                    out_walls.append(walls[i] + (w,))
                    reached = order
            n_beams = sum(k[0].shape[0] for k in kids)
            if len(out_A) > max_images or n_beams > 5 * max_images:
                if truncate:
                    done = np.array(out_order) < order
                    return ImageSet(
                        A=np.array(out_A, dtype=np.float64).reshape(-1, 2, 2)[done],
                        b=np.array(out_b, dtype=np.float64).reshape(-1, 2)[done],
                        order=np.array(out_order, dtype=np.int64)[done],
                        walls=tuple(wl for wl, k in zip(out_walls, done, strict=True) if k),
                        max_order=order - 1,
                        truncated=True,
                    )
                raise ValueError(
                    f"more than max_images={max_images} image sources (or beams) up to "
                    f"order {order}; lower the order or max_path_m"
                )
            # a beam through a single point (a corner) is output but not followed on
            wide = keep & ((hi - lo) * lengths[w] > _POINT_APERTURE_M)
            go = np.flatnonzero(np.any(wide, axis=1))
            if go.size:
                c, d = seg[w, 0], seg[w, 1]
                kids.append((
                    A2[go], b2[go], np.full(go.size, w), wide[go],
                    c + lo[go, :, None] * (d - c), c + hi[go, :, None] * (d - c),
                ))
                kid_walls.extend(walls[i] + (w,) for i in go)
        if not kids:
            break
        A, b, last, alive, ap0, ap1 = (np.concatenate(parts) for parts in zip(*kids, strict=True))
        walls = kid_walls
    return ImageSet(
        A=np.array(out_A, dtype=np.float64).reshape(-1, 2, 2),
        b=np.array(out_b, dtype=np.float64).reshape(-1, 2),
        order=np.array(out_order, dtype=np.int64),
        walls=tuple(out_walls),
        max_order=reached,
    )


def _clip_beam(
    sources: FloatArray, ap0: FloatArray, ap1: FloatArray, target: FloatArray
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Part of segment ``target`` reached by rays from each source through its aperture.

    The region is the wedge from the source spanned by the aperture ``ap0 - ap1``, beyond
    the aperture: three half-planes, against which ``target`` is clipped (Cyrus-Beck) for
    every source at once. Returns the parameter interval ``[lo, hi]`` along ``target`` and
    whether it is non-empty (with a small tolerance, so a corner point counts).
    """
    s, a, bb = sources, ap0, ap1
    c, d = target[0], target[1]

    def cross(u: FloatArray, v: FloatArray) -> FloatArray:
        return np.asarray(u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0])

    orient = cross(a - s, bb - s)  # (m,)
    sign = np.where(orient >= 0, 1.0, -1.0)

    def halfplanes(q: FloatArray) -> FloatArray:
        # q on bb's side of line s-a, on a's side of line s-bb, and beyond line a-bb
        return np.stack(
            [
                sign * cross(a - s, q - s),
                -sign * cross(bb - s, q - s),
                -sign * cross(bb - a, q - a),
            ]
        )

    fc = halfplanes(np.broadcast_to(c, s.shape))
    fd = halfplanes(np.broadcast_to(d, s.shape))
    scale = np.linalg.norm(d - c) * (
        np.linalg.norm(bb - a, axis=-1) + np.linalg.norm(a - s, axis=-1)
    )
    tol = 1e-9 * scale
    lo = np.zeros(s.shape[:-1])
    hi = np.ones(s.shape[:-1])
    for k in range(3):
        f0, f1 = fc[k], fd[k]
        df = f1 - f0
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (-tol - f0) / df
        lo = np.where(df > 0, np.maximum(lo, u), lo)
        hi = np.where(df < 0, np.minimum(hi, u), hi)
        hi = np.where((df == 0) & (f0 < -tol), -1.0, hi)
    degenerate = np.abs(orient) <= 1e-12 * scale
    ok = (lo <= hi) & ~degenerate
    return np.clip(lo, 0.0, 1.0), np.clip(hi, 0.0, 1.0), ok
