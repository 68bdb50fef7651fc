"""Which echo peaks a set of walls explains, by the forward model (mapping.forward)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mapping.forward import ForwardParams, WallSet, echoes_batch, shared_vertices, vertex_paths
from mapping.signal import SonarConfig
from mapping.walls._peaks import PeakObservations

BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]


def _block_poses(obs: PeakObservations) -> tuple[IntArray, IntArray, NDArray[np.float64]]:
    """Each peak's block (index into the poses), each block's first peak and the pose of
    every block (n_blocks, 3)."""
    key = obs.run * 1_000_000 + obs.block
    uniq, inv = np.unique(key, return_inverse=True)
    first = np.zeros(uniq.size, dtype=np.int64)
    first[inv[::-1]] = np.arange(obs.size)[::-1]
    return inv, first, np.stack([obs.x_m[first], obs.y_m[first], obs.travel_rad[first]], axis=1)


def explained(obs: PeakObservations, walls: WallSet, config: SonarConfig, max_order: int,
              range_tol_m: float, cos_tol: float, min_order: int = 1,
              must_use: int = -1) -> BoolArray:
    """Peaks matched by a predicted echo of ``walls`` (range and Doppler cosine within tol).

    Only echoes of order >= ``min_order`` count, and, if ``must_use`` >= 0, only echoes whose
    path touches wall ``must_use``.
    """
    out = np.zeros(obs.size, dtype=bool)
    if obs.size == 0 or walls.n == 0:
        return out
    inv, _, poses = _block_poses(obs)
    batch = echoes_batch(walls, poses, 0.0, config, ForwardParams(max_order=max_order))
    ok = (batch.order >= min_order)
    if must_use >= 0:
        ok &= np.any(batch.walls == must_use, axis=2)
    ok &= np.arange(batch.range_m.shape[1])[None, :] < batch.count[:, None]
    r = np.where(ok, batch.range_m, np.nan)
    c = np.where(ok, batch.cos_doppler, np.nan)
    if max_order >= 2 and min_order <= 2:
        vr, vc = vertex_echoes(walls, poses, must_use)
        r, c = np.concatenate([r, vr], axis=1), np.concatenate([c, vc], axis=1)
    r, c = r[inv], c[inv]
    dr = np.abs(r - obs.range_m[:, None])
    dc = np.abs(c - np.cos(obs.angle_rad)[:, None])
    match = (dr <= range_tol_m) & (dc <= cos_tol)
    out[:] = np.any(match, axis=1)
    return out


def _cross(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])


def vertex_echoes(walls: WallSet, poses: NDArray[np.float64],
                  must_use: int = -1) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Retro-reflection at shared vertices of inside corners: (range, cos) per pose (n, m).

    The monostatic two-bounce echo of a right-angle corner bounces at the vertex itself
    (range ``|C - p|``, Doppler of the direction to C). A fitted corner is never exactly
    90 deg, and the exact image paths of a corner a fraction of a degree off either vanish
    or split; this keeps the echo the sonar hears. Valid where the pose lies inside the
    convex wedge of the two walls and the line of sight to C is clear
    (:func:`mapping.forward.vertex_paths`); NaN elsewhere.
    """
    corners = [v for v in shared_vertices(walls.segments_m)
               if must_use < 0 or must_use in v[:2]]
    dist, ok = vertex_paths(walls.segments_m, poses, corners)
    c = np.full(dist.shape, np.nan)
    for m, (_, _, vertex) in enumerate(corners):
        bearing = np.arctan2(vertex[1] - poses[:, 1], vertex[0] - poses[:, 0])
        c[:, m] = np.cos(bearing - poses[:, 2])
    return np.where(ok, dist, np.nan), np.where(ok, c, np.nan)


def occluded(obs: PeakObservations, normal_rad: float, walls: WallSet) -> BoolArray:
    """Peaks whose first-order echo off the line of normal ``normal_rad`` would have to pass
    through one of ``walls``: the leg from the pose to the specular point ``p + r n`` is
    blocked (a wall behind a wall is heard only by multiple bounces)."""
    p = np.stack([obs.x_m, obs.y_m], axis=1)
    n = np.array([np.cos(normal_rad), np.sin(normal_rad)])
    q = p + obs.range_m[:, None] * n
    out = np.zeros(obs.size, dtype=bool)
    seg = walls.segments_m
    r = q - p
    for w in range(walls.n):
        a, d = seg[w, 0], seg[w, 1] - seg[w, 0]
        den = _cross(r, np.broadcast_to(d, r.shape))
        qa = a - p
        with np.errstate(divide="ignore", invalid="ignore"):
            s = _cross(qa, np.broadcast_to(d, r.shape)) / den
            u = _cross(qa, r) / den
        out |= (np.abs(den) > 1e-15) & (s > 1e-9) & (s < 1 - 0.02) & (u >= 0) & (u <= 1)
    return out


def heard_blocks(obs: PeakObservations, walls: WallSet, index: int, config: SonarConfig,
                 range_tol_m: float, cos_tol: float, snr: float, min_relative: float,
                 max_range_m: float) -> tuple[int, int]:
    """(blocks where wall ``index`` must give a first-order echo, blocks that have it).

    "Must" means: the forward model (all ``walls``, occlusion included) predicts it within
    ``max_range_m`` with an amplitude 1.5 times above the level a peak must reach in that
    block (``snr`` times its noise, ``min_relative`` times its strongest peak).
    """
    if obs.size == 0:
        return 0, 0
    inv, first, poses = _block_poses(obs)
    batch = echoes_batch(walls, poses, 0.0, config,
                         ForwardParams(max_order=1, max_range_m=max_range_m))
    own = (batch.walls[..., 0] == index) & (batch.order == 1)
    top = np.zeros(poses.shape[0])
    np.maximum.at(top, inv, obs.value)
    level = np.maximum(snr * obs.noise[first], min_relative * top)
    loud = np.abs(batch.amplitude) >= 1.5 * level[:, None]
    must = own & loud
    rows = np.nonzero(must.any(axis=1))[0]
    if rows.size == 0:
        return 0, 0
    r = np.where(must, batch.range_m, np.nan)[rows]
    c = np.where(must, batch.cos_doppler, np.nan)[rows]
    heard = 0
    for row, pr, pc in zip(rows, r, c, strict=True):
        m = inv == row
        dr = np.abs(obs.range_m[m][:, None] - pr[None, :])
        dc = np.abs(np.cos(obs.angle_rad[m])[:, None] - pc[None, :])
        heard += int(np.any((dr <= range_tol_m) & (dc <= cos_tol)))
    return int(rows.size), heard


def heard_sides(obs: PeakObservations, walls: WallSet, config: SonarConfig, range_tol_m: float,
                cos_tol: float, max_range_m: float) -> IntArray:
    """Blocks in which each wall's first-order echo was heard, per side of the wall the robot
    stood on: (n, 2), column 0 left of the wall's direction ``a -> b``, column 1 right.

    A specular echo shows a wall's face towards the sonar; a wall heard from one side only
    is one face of something whose other side was never heard (a shelf stack heard from one
    aisle, a room's wall heard from inside). The forward model (occlusion by the other walls
    included) gives each pose's first-order echo of each wall; it was heard when a peak of
    that block lies within ``range_tol_m`` and ``cos_tol`` of it.
    """
    out = np.zeros((walls.n, 2), dtype=np.int64)
    if obs.size == 0 or walls.n == 0:
        return out
    inv, _, poses = _block_poses(obs)
    batch = echoes_batch(walls, poses, 0.0, config,
                         ForwardParams(max_order=1, max_range_m=max_range_m))
    valid = np.arange(batch.range_m.shape[1])[None, :] < batch.count[:, None]
    seg = walls.segments_m
    cos_peak = np.cos(obs.angle_rad)
    for w in range(walls.n):
        own = valid & (batch.walls[..., 0] == w) & (batch.order == 1)
        rows = np.flatnonzero(own.any(axis=1))
        if rows.size == 0:
            continue
        r = np.where(own, batch.range_m, np.nan)[rows]
        c = np.where(own, batch.cos_doppler, np.nan)[rows]
        side = _cross(seg[w, 1] - seg[w, 0], poses[rows, :2] - seg[w, 0])
        for row, pr, pc, s in zip(rows, r, c, side, strict=True):
            m = inv == row
            dr = np.abs(obs.range_m[m][:, None] - pr[None, :])
            dc = np.abs(cos_peak[m][:, None] - pc[None, :])
            if np.any((dr <= range_tol_m) & (dc <= cos_tol)):
                out[w, 0 if s > 0 else 1] += 1
    return out
