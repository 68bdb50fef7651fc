"""Plain numpy twin of the numba FDTD kernels of :mod:`mapping.simulate.fdtd` (tests and the
benchmark baseline of ``benchmarks/fdtd.py`` only).

:func:`run_steps_numpy` advances the fields one step at a time with whole-array numpy
operations, the same arithmetic per element as ``_kernels._run_steps`` and
``_kernels._run_sweeps``; :class:`NumpyFdtdSolver` is an
:class:`~mapping.simulate.fdtd.FdtdSolver` that steps with it. ``test_fdtd.py`` compares the two.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mapping.simulate.fdtd import FdtdSolver

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class NumpyFdtdSolver(FdtdSolver):
    """:class:`FdtdSolver` whose :meth:`run` steps with :func:`run_steps_numpy` (its
    ``backend`` is ignored)."""

    def run(self, src_i: IntArray, src_j: IntArray, src_w: FloatArray, src_g: FloatArray,
            rx_i: IntArray, rx_j: IntArray, rx_w: FloatArray) -> FloatArray:
        n = int(np.asarray(src_g).shape[0])
        out = np.zeros((n, self.p.shape[0]))
        c = self.coef
        beta = self.walls.beta.astype(self.dtype)
        run_steps_numpy(self.p, self.qx, self.qy, self.psx, c.aqx, c.bqx, c.aqy, c.bqy,
                        c.apx, c.bpx, c.apy, c.bpy, self.dtype.type(c.kp), self.grid.pml_cells,
                        self.walls.wx, self.walls.wy, beta > 0, beta, self.offset, self.flush,
                        np.asarray(src_i, dtype=np.int64), np.asarray(src_j, dtype=np.int64),
                        np.asarray(src_w, dtype=np.float64), np.asarray(src_g, dtype=np.float64),
                        np.asarray(rx_i, dtype=np.int64), np.asarray(rx_j, dtype=np.int64),
                        np.asarray(rx_w, dtype=np.float64), out)
        return out


def split_numpy(p, sx, dqx, dqy, apx, bpx, apy, bpy, offset, flush):
    """Split-field PML pressure update of one field: (new x part, new pressure)."""
    px = apx[:, None] * sx - bpx[:, None] * dqx
    py = apy[None, :] * (p - offset - sx) - bpy[None, :] * dqy
    px = np.where(np.abs(px) < flush, px.dtype.type(0), px)
    py = np.where(np.abs(py) < flush, py.dtype.type(0), py)
    return px, offset + px + py


def step_numpy(p, qx, qy, psx, aqx, bqx, aqy, bqy, apx, bpx, apy, bpy, kp, npml,
                wx_mask, wy_mask, imp_mask, imp_beta_grid, offset, flush):
    """One step of eqs. 9-11 as whole-array numpy operations (velocities, then pressure)."""
    nf, nx, ny = p.shape
    zero = p.dtype.type(0)
    pml_cell = np.zeros((nx, ny), dtype=bool)
    pml_cell[:npml, :] = True
    pml_cell[nx - npml:, :] = True
    pml_cell[:, :npml] = True
    pml_cell[:, ny - npml:] = True
    for f in range(nf):
        vx = aqx[1:nx, None] * qx[f, 1:nx] - bqx[1:nx, None] * (p[f, 1:] - p[f, :-1])
        damped_x = (aqx[1:nx] != 1)[:, None]
        vx = np.where(damped_x & (np.abs(vx) < flush), zero, vx)
        qx[f, 1:nx] = vx
        vy = aqy[None, 1:ny] * qy[f, :, 1:ny] - bqy[None, 1:ny] * (p[f, :, 1:] - p[f, :, :-1])
        damped_y = (aqy[1:ny] != 1)[None, :]
        vy = np.where(damped_y & (np.abs(vy) < flush), zero, vy)
        qy[f, :, 1:ny] = vy
        if f == 0:
            qx[0][wx_mask] = zero
            qy[0][wy_mask] = zero
        dqx = qx[f, 1:] - qx[f, :-1]
        dqy = qy[f, :, 1:] - qy[f, :, :-1]
        plain = p[f] - kp * (dqx + dqy)
        px, split = split_numpy(p[f], psx[f], dqx, dqy, apx, bpx, apy, bpy, offset, flush)
        new = np.where(pml_cell, split, plain)
        psx[f] = np.where(pml_cell, px, psx[f])
        if f == 0:
            beta = imp_beta_grid
            corrected = offset + ((new - offset) - beta * (p[f] - offset)) / (1 + beta)
            new = np.where(imp_mask, corrected, new)
        p[f] = new


def run_steps_numpy(p, qx, qy, psx, aqx, bqx, aqy, bqy, apx, bpx, apy, bpy, kp, npml,
                     wx_mask, wy_mask, imp_mask, imp_beta_grid, offset, flush,
                     src_i, src_j, src_w, src_g, rx_i, rx_j, rx_w, out):
    """Twin of ``_kernels._run_steps`` (walls and impedance cells given as dense masks)."""
    for n in range(src_g.shape[0]):
        step_numpy(p, qx, qy, psx, aqx, bqx, aqy, bqy, apx, bpx, apy, bpy, kp, npml,
                    wx_mask, wy_mask, imp_mask, imp_beta_grid, offset, flush)
        for f in range(p.shape[0]):
            for k in range(4):
                p[f, src_i[n, k], src_j[n, k]] += src_w[n, k] * src_g[n]
            out[n, f] = np.sum(rx_w[n] * (p[f, rx_i[n], rx_j[n]] - offset))
