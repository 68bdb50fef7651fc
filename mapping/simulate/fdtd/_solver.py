"""The FDTD solver: fields of one grid and their time stepping (paper eqs. 9-11).

The only user of the numba kernels in :mod:`mapping.simulate.fdtd._kernels`; validates and
converts every input, and packs it into the kernels' records, before calling them. Also the
discrete energy the scheme conserves.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.simulate.fdtd import _kernels as _k
from mapping.simulate.fdtd._config import FdtdConfig, check_courant
from mapping.simulate.fdtd._grid import (
    FdtdGrid,
    WallNodes,
    _csr_rows,
    bilinear_stencil,
    make_coefficients,
)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_FLUSH = 1e-30
#: Below this many field cells the kernel runs on one thread (per-sweep barriers dominate).
_SMALL_GRID_CELLS = 200_000
#: Default time steps per sweep over the rows (temporal blocking, ``_k._run_sweeps``).
#: Measured on the paper-scene domain (970 x 771, two fields, float32, one thread, helpers
#: not yet inlined, interleaved): 1, 2, 4, 8, 16 steps per sweep ran 0.95, 1.14, 1.36, 1.54,
#: 1.68x the one-step kernel; 32 and 64 within 2 % of 16 in a second run.
STEPS_PER_SWEEP = 16
_BACKENDS = ("numba", "numba-step")


# ---- the solver ---------------------------------------------------------------------------
class FdtdSolver:
    """Fields of one grid (``n_fields`` = 2: with walls, without) and their time stepping.

    A thin stateful object over the numba kernels. ``backend="numba"`` (default) advances
    ``steps_per_sweep`` steps per sweep over the rows (temporal blocking,
    :func:`_k._run_sweeps`) on ``n_chunks`` row chunks (default: one per numba thread;
    both are reduced so that every chunk is at least ``2 steps_per_sweep`` rows wide);
    ``"numba-step"`` is the previous one-step-per-sweep kernel (:func:`_k._run_steps`,
    benchmark baseline); both give the same fields bit for bit. (The plain numpy twin of
    the kernels lives with the tests, ``tests/mapping/simulate/fdtd/naive.py``.)
    """

    def __init__(self, grid: FdtdGrid, fdtd: FdtdConfig, c: float, walls: WallNodes | None = None,
                 n_fields: int = 2, backend: str = "numba", *,
                 steps_per_sweep: int = STEPS_PER_SWEEP, n_chunks: int | None = None) -> None:
        check_courant(fdtd, c)
        if n_fields not in (1, 2):
            raise ValueError(f"n_fields must be 1 or 2, got {n_fields}")
        if backend not in _BACKENDS:
            raise ValueError(f"backend must be one of {_BACKENDS}, got {backend!r}")
        if steps_per_sweep < 1:
            raise ValueError(f"steps_per_sweep must be >= 1, got {steps_per_sweep}")
        if n_chunks is not None and n_chunks < 1:
            raise ValueError(f"n_chunks must be >= 1 or None, got {n_chunks}")
        self.grid, self.fdtd, self.c, self.backend = grid, fdtd, c, backend
        self.steps_per_sweep, self.n_chunks = steps_per_sweep, n_chunks
        self.walls = walls if walls is not None else WallNodes.none(grid)
        self.coef = make_coefficients(grid, fdtd, c)
        dtype = np.dtype(fdtd.dtype)
        self.dtype = dtype
        self.offset = dtype.type(1e-6 if fdtd.denormal_guard else 0.0)
        self.flush = dtype.type(_FLUSH if fdtd.denormal_guard else 0.0)
        nx, ny = grid.shape
        self.p = np.full((n_fields, nx, ny), self.offset, dtype=dtype)
        self.qx = np.zeros((n_fields, nx + 1, ny), dtype=dtype)
        self.qy = np.zeros((n_fields, nx, ny + 1), dtype=dtype)
        self.psx = np.zeros((n_fields, nx, ny), dtype=dtype)
        self._wx = _csr_rows(self.walls.wx)
        self._wy = _csr_rows(self.walls.wy)
        imp = self.walls.beta > 0
        self._imp_ptr, self._imp_col = _csr_rows(imp)
        self._imp_beta = self.walls.beta[imp].astype(dtype)
        self._imp_buf = np.zeros(self._imp_beta.size, dtype=dtype)

    @property
    def pressure(self) -> NDArray[Any]:
        """Pressure fields without the storage offset, (n_fields, nx, ny)."""
        return np.asarray(self.p - self.offset)

    def run(self, src_i: IntArray, src_j: IntArray, src_w: FloatArray, src_g: FloatArray,
            rx_i: IntArray, rx_j: IntArray, rx_w: FloatArray) -> FloatArray:
        """Advance ``len(src_g)`` steps; step n adds ``w * g[n]`` at the source nodes and
        records the bilinear receiver pressure after it. Returns (n, n_fields)."""
        n = int(np.asarray(src_g).shape[0])
        out = np.zeros((n, self.p.shape[0]))
        drive = _k._Drive(np.ascontiguousarray(src_i, dtype=np.int64),
                          np.ascontiguousarray(src_j, dtype=np.int64),
                          np.ascontiguousarray(src_w, dtype=np.float64),
                          np.ascontiguousarray(src_g, dtype=np.float64),
                          np.ascontiguousarray(rx_i, dtype=np.int64),
                          np.ascontiguousarray(rx_j, dtype=np.int64),
                          np.ascontiguousarray(rx_w, dtype=np.float64))
        c = self.coef
        fields = _k._Fields(self.p, self.qx, self.qy, self.psx)
        coef = _k._Coefficients(c.aqx, c.bqx, c.aqy, c.bqy, c.apx, c.bpx, c.apy, c.bpy,
                                self.dtype.type(c.kp), self.grid.pml_cells)
        walls = _k._Walls(*self._wx, *self._wy, self._imp_ptr, self._imp_col, self._imp_beta,
                          self._imp_buf, self.offset, self.flush)
        import numba

        threads = numba.get_num_threads()
        if self.p.size < _SMALL_GRID_CELLS:  # a thread barrier per sweep costs more
            numba.set_num_threads(1)
        try:
            if self.backend == "numba":
                chunks, depth = sweep_plan(self.grid.shape[0], self.steps_per_sweep,
                                           self.n_chunks or numba.get_num_threads())
                outk = np.zeros((n, self.p.shape[0], 4))
                _k._run_sweeps(fields, coef, walls, drive, outk, chunks, depth)
                # receiver nodes summed in stencil order, as the one-step kernel does
                out[...] = ((outk[..., 0] + outk[..., 1]) + outk[..., 2]) + outk[..., 3]
            else:
                _k._run_steps(fields, coef, walls, drive, out, _n_chunks(self.grid.shape[0]))
        finally:
            numba.set_num_threads(threads)
        return out

    def run_static(self, src_xy: FloatArray, rx_xy: FloatArray, g: FloatArray) -> FloatArray:
        """:meth:`run` with a static source and receiver (points (2,))."""
        n = len(g)
        si, sj, sw = bilinear_stencil(np.asarray(src_xy)[None], self.grid)
        ri, rj, rw = bilinear_stencil(np.asarray(rx_xy)[None], self.grid)
        rep = (n, 1)
        return self.run(np.tile(si, rep), np.tile(sj, rep), np.tile(sw, rep), np.asarray(g),
                        np.tile(ri, rep), np.tile(rj, rep), np.tile(rw, rep))

    def state_arrays(self) -> dict[str, NDArray[Any]]:
        """Copy of the fields for a checkpoint."""
        return {"p": self.p.copy(), "qx": self.qx.copy(), "qy": self.qy.copy(),
                "psx": self.psx.copy()}

    def load_state(self, arrays: dict[str, NDArray[Any]]) -> None:
        """Restore fields written by :meth:`state_arrays`; ``ValueError`` on a mismatch."""
        for name in ("p", "qx", "qy", "psx"):
            cur = getattr(self, name)
            new = np.asarray(arrays[name])
            if new.shape != cur.shape or new.dtype != cur.dtype:
                raise ValueError(f"checkpoint field {name!r} has shape {new.shape} {new.dtype}, "
                                 f"expected {cur.shape} {cur.dtype}")
            cur[...] = new


def _n_chunks(nx: int) -> int:
    import numba

    return max(1, min(nx // 2, 4 * numba.get_num_threads()))


def sweep_plan(nx: int, steps_per_sweep: int, n_chunks: int) -> tuple[int, int]:
    """(chunks, steps per sweep) for ``nx`` rows: at most ``nx // 2`` chunks, and at most
    half the narrowest chunk's rows steps per sweep (the temporally blocked kernel needs
    every chunk at least ``2 * steps`` rows wide)."""
    chunks = max(1, min(n_chunks, nx // 2))
    depth = max(1, steps_per_sweep)
    if chunks > 1:
        depth = min(depth, (nx // chunks) // 2)
    return chunks, depth


def leapfrog_energy(p_prev: NDArray[Any], p: NDArray[Any], qx: NDArray[Any], qy: NDArray[Any],
                    density_kg_m3: float, c: float, grid_step_m: float) -> float:
    """Discrete energy per unit depth (J/m) exactly conserved by eqs. 9-11 in a rigid box.

    ``E^(n+1/2) = dx^2 [ sum p^n p^(n+1) / (2 rho c^2) + rho / 2 sum |q^(n+1/2)|^2 ]``
    (pressures without the storage offset). Positive definite for Courant <= 1 / sqrt(2).
    """
    pp = np.sum(np.asarray(p_prev, np.float64) * np.asarray(p, np.float64))
    qq = np.sum(np.asarray(qx, np.float64) ** 2) + np.sum(np.asarray(qy, np.float64) ** 2)
    e = pp / (2 * density_kg_m3 * c * c) + density_kg_m3 / 2 * qq
    return float(e * grid_step_m**2)
