"""The FDTD grid: fitting it to a scene, walls on velocity nodes, stencils and PML coefficients.

Conventions (see :mod:`mapping.simulate.fdtd`): cell ``(i, j)`` has its pressure node at
``origin_m + (i, j) * grid_step_m``, velocity nodes half a cell before it; cell centres sit at
odd multiples of ``grid_step_m / 2`` so walls on round coordinates fall on velocity nodes. The
moving source and receiver use the bilinear weights of the direct method (paper eqs. 12-17); the
outer border is a graded perfectly matched layer (coefficients of eqs. 9-11).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.simulate._base import SceneLike
from mapping.simulate.fdtd._config import FdtdConfig

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


# ---- grid, walls, stencils ----------------------------------------------------------------
@dataclass(frozen=True)
class FdtdGrid:
    """Pressure nodes at ``origin_m + (i, j) * grid_step_m``, i < nx, j < ny; the outer
    ``pml_cells`` on each side are the PML."""

    origin_m: tuple[float, float]
    shape: tuple[int, int]
    grid_step_m: float
    pml_cells: int

    def interior_bounds_m(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the non-PML region (pressure node coordinates)."""
        n, dx = self.pml_cells, self.grid_step_m
        x0, y0 = self.origin_m
        nx, ny = self.shape
        return (x0 + n * dx, x0 + (nx - 1 - n) * dx, y0 + n * dx, y0 + (ny - 1 - n) * dx)


def fit_grid(points_m: FloatArray, fdtd: FdtdConfig) -> FdtdGrid:
    """Smallest grid holding ``points_m`` (n, 2) plus the margin plus the PML.

    Cell centres sit at odd multiples of dx / 2 (walls on round coordinates land on
    velocity nodes).
    """
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    if pts.size == 0 or not np.all(np.isfinite(pts)):
        raise ValueError("points_m must be a non-empty finite (n, 2) array")
    dx = fdtd.grid_step_m
    lo = pts.min(axis=0) - fdtd.margin_m
    hi = pts.max(axis=0) + fdtd.margin_m
    first = np.floor(lo / dx - 0.5) - fdtd.pml_cells
    last = np.ceil(hi / dx - 0.5) + fdtd.pml_cells
    shape = (int(last[0] - first[0]) + 1, int(last[1] - first[1]) + 1)
    origin = ((first[0] + 0.5) * dx, (first[1] + 0.5) * dx)
    return FdtdGrid(origin_m=(float(origin[0]), float(origin[1])), shape=shape,
                    grid_step_m=dx, pml_cells=fdtd.pml_cells)


def rasterize_walls(segments_m: FloatArray, grid: FdtdGrid) -> tuple[NDArray[np.bool_],
                                                                     NDArray[np.bool_]]:
    """Velocity nodes whose link between two pressure nodes crosses a wall segment.

    Returns ``(wx, wy)`` of shapes (nx + 1, ny) and (nx, ny + 1). Every link intersecting a
    segment is blocked, so a closed polygon is watertight on the grid.
    """
    seg = np.asarray(segments_m, dtype=np.float64).reshape(-1, 2, 2)
    nx, ny = grid.shape
    dx = grid.grid_step_m
    x0, y0 = grid.origin_m
    wx = np.zeros((nx + 1, ny), dtype=bool)
    wy = np.zeros((nx, ny + 1), dtype=bool)
    for (px, py), (qx, qy) in seg:
        _mark_links(wx, px, py, qx, qy, x0, y0, dx, nx, ny)
        _mark_links(wy.T, py, px, qy, qx, y0, x0, dx, ny, nx)
    return wx, wy


def _mark_links(w: NDArray[np.bool_], px: float, py: float, qx: float, qy: float,
                x0: float, y0: float, dx: float, nx: int, ny: int) -> None:
    """Mark x-links (node rows j at y0 + j dx) crossed by segment (px,py)-(qx,qy)."""
    if qy == py:
        return
    j = np.arange(max(0, math.ceil((min(py, qy) - y0) / dx)),
                  min(ny - 1, math.floor((max(py, qy) - y0) / dx)) + 1)
    if j.size == 0:
        return
    t = (y0 + j * dx - py) / (qy - py)
    u = (px + t * (qx - px) - x0) / dx  # crossing in pressure-node units
    i = np.floor(u).astype(np.int64) + 1  # link i joins nodes i-1 and i
    ok = (i >= 1) & (i <= nx - 1)
    w[i[ok], j[ok]] = True
    exact = ok & (u == np.floor(u)) & (i - 1 >= 1)
    w[i[exact] - 1, j[exact]] = True


def bilinear_stencil(points_m: FloatArray, grid: FdtdGrid) -> tuple[IntArray, IntArray,
                                                                   FloatArray]:
    """Nodes and weights of the direct method (eqs. 12-17) for points (n, 2).

    Returns ``(i, j, w)`` each (n, 4) in the order (floor, floor), (floor+1, floor),
    (floor+1, floor+1), (floor, floor+1); ``w = (1 -+ zeta)(1 -+ eta) / 4`` with
    ``zeta = 2 (u - floor(u)) - 1``, ``u = (x - x0) / dx``; rows sum to 1.
    """
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    u = (pts[:, 0] - grid.origin_m[0]) / grid.grid_step_m
    v = (pts[:, 1] - grid.origin_m[1]) / grid.grid_step_m
    i0, j0 = np.floor(u), np.floor(v)
    nx, ny = grid.shape
    if np.any((i0 < 0) | (i0 + 1 > nx - 1) | (j0 < 0) | (j0 + 1 > ny - 1)):
        raise ValueError("points_m: a source or receiver position lies outside the grid")
    zeta, eta = 2 * (u - i0) - 1, 2 * (v - j0) - 1
    ii = i0.astype(np.int64)[:, None] + np.array([0, 1, 1, 0])
    jj = j0.astype(np.int64)[:, None] + np.array([0, 0, 1, 1])
    w = np.stack([(1 - zeta) * (1 - eta), (1 + zeta) * (1 - eta),
                  (1 + zeta) * (1 + eta), (1 - zeta) * (1 + eta)], axis=1) / 4
    return ii, jj, w


# ---- coefficients -------------------------------------------------------------------------
@dataclass(frozen=True)
class FdtdCoefficients:
    """Update coefficients (eqs. 9-11 with the PML), in the field dtype."""

    aqx: NDArray[Any]
    bqx: NDArray[Any]
    aqy: NDArray[Any]
    bqy: NDArray[Any]
    apx: NDArray[Any]
    bpx: NDArray[Any]
    apy: NDArray[Any]
    bpy: NDArray[Any]
    kp: float
    kq: float


def _pml_sigma(pos: NDArray[Any], n: int, npml: int, fdtd: FdtdConfig, c: float) -> FloatArray:
    """Absorption sigma (1/s) at node positions ``pos`` in pressure-node units."""
    if npml == 0:
        return np.zeros_like(pos)
    depth = np.maximum(np.maximum((npml - 0.5) - pos, pos - (n - npml - 0.5)), 0.0) / npml
    width = npml * fdtd.grid_step_m
    smax = (fdtd.pml_order + 1) * c * math.log(1 / fdtd.pml_reflection) / (2 * width)
    return np.asarray(smax * depth ** fdtd.pml_order)


def make_coefficients(grid: FdtdGrid, fdtd: FdtdConfig, c: float) -> FdtdCoefficients:
    """PML-graded coefficients: ``a = (1 - s dt/2) / (1 + s dt/2)``, ``b = k / (1 + s dt/2)``."""
    dt, dx, rho = fdtd.time_step_s, fdtd.grid_step_m, fdtd.density_kg_m3
    dtype = np.dtype(fdtd.dtype)
    kq, kp = dt / (rho * dx), rho * c * c * dt / dx
    nx, ny = grid.shape
    npml = grid.pml_cells

    def ab(sig: FloatArray, k: float) -> tuple[NDArray[Any], NDArray[Any]]:
        h = sig * dt / 2
        return ((1 - h) / (1 + h)).astype(dtype), (k / (1 + h)).astype(dtype)

    aqx, bqx = ab(_pml_sigma(np.arange(nx + 1) - 0.5, nx, npml, fdtd, c), kq)
    aqy, bqy = ab(_pml_sigma(np.arange(ny + 1) - 0.5, ny, npml, fdtd, c), kq)
    apx, bpx = ab(_pml_sigma(np.arange(nx, dtype=float), nx, npml, fdtd, c), kp)
    apy, bpy = ab(_pml_sigma(np.arange(ny, dtype=float), ny, npml, fdtd, c), kp)
    return FdtdCoefficients(aqx, bqx, aqy, bqy, apx, bpx, apy, bpy,
                            float(dtype.type(kp)), float(dtype.type(kq)))


@dataclass(frozen=True)
class WallNodes:
    """Walls on the grid: rigid velocity nodes and finite-impedance pressure cells."""

    wx: NDArray[np.bool_]
    wy: NDArray[np.bool_]
    beta: FloatArray  # (nx, ny): implicit impedance coefficient, 0 where none

    @classmethod
    def none(cls, grid: FdtdGrid) -> WallNodes:
        """No walls."""
        nx, ny = grid.shape
        return cls(np.zeros((nx + 1, ny), bool), np.zeros((nx, ny + 1), bool), np.zeros((nx, ny)))


def wall_nodes(segments_m: FloatArray, impedance_pa_s_m: FloatArray, grid: FdtdGrid,
               fdtd: FdtdConfig, c: float) -> WallNodes:
    """Rasterize walls; a finite impedance Z adds ``beta = rho c^2 dt / (2 Z dx)`` to the
    pressure cells on both sides (locally reacting surface, p = Z q_n on each face)."""
    seg = np.asarray(segments_m, dtype=np.float64).reshape(-1, 2, 2)
    z = np.broadcast_to(np.asarray(impedance_pa_s_m, dtype=np.float64), (seg.shape[0],))
    if np.any(~(z > 0)):
        raise ValueError("impedance_pa_s_m must be > 0 (inf for rigid walls)")
    wx_all, wy_all = rasterize_walls(seg, grid)
    nx, ny = grid.shape
    beta = np.zeros((nx, ny))
    k = fdtd.density_kg_m3 * c * c * fdtd.time_step_s / (2 * fdtd.grid_step_m)
    for s, zk in zip(seg, z, strict=True):
        if not math.isfinite(zk):
            continue
        wx, wy = rasterize_walls(s[None], grid)
        ix, jx = np.nonzero(wx)
        np.add.at(beta, (ix - 1, jx), k / zk)
        np.add.at(beta, (ix, jx), k / zk)
        iy, jy = np.nonzero(wy)
        np.add.at(beta, (iy, jy - 1), k / zk)
        np.add.at(beta, (iy, jy), k / zk)
    return WallNodes(wx_all, wy_all, beta)


def _csr_rows(mask: NDArray[np.bool_]) -> tuple[IntArray, IntArray]:
    rows, cols = np.nonzero(mask)
    ptr = np.zeros(mask.shape[0] + 1, dtype=np.int64)
    np.add.at(ptr, rows + 1, 1)
    return np.cumsum(ptr), cols.astype(np.int64)


def scene_walls(scene: SceneLike, density_kg_m3: float, c: float) -> tuple[FloatArray, FloatArray]:
    """Segments (W, 2, 2) and normal impedances (W,) of a scene.

    The impedance follows from the scene's normal-incidence reflection coefficient R,
    ``Z = rho c (1 + R) / (1 - R)`` (R = 1: rigid, Z = inf), so both engines agree.
    """
    seg = np.asarray(scene.segments(), dtype=np.float64).reshape(-1, 2, 2)
    r = np.asarray(scene.reflection_coefficients(), dtype=np.float64).reshape(-1)
    if r.shape[0] != seg.shape[0] or np.any(~((r > -1) & (r <= 1))):
        raise ValueError("scene reflection coefficients must be one per wall, in (-1, 1]")
    with np.errstate(divide="ignore"):
        z = np.where(r >= 1, np.inf, density_kg_m3 * c * (1 + r) / np.maximum(1 - r, 1e-300))
    return seg, z
