"""Private numba kernels of the staggered-grid FDTD (paper eqs. 9-11); imported only by
``mapping/simulate/fdtd/_solver.py`` (:class:`~mapping.simulate.fdtd.FdtdSolver`), which
validates every input first and hands the kernels four records: :class:`_Fields`,
:class:`_Coefficients`, :class:`_Walls` and :class:`_Drive`.

Layout (first index x / row ``i``, second index y / column ``j``; ``f`` = field):

- ``p[f, i, j]``   pressure at cell centre (i, j), stored with a constant ``offset`` added
  (keeps tiny values out of the subnormal range, see ``fdtd.py``);
- ``qx[f, i, j]``  x velocity at (i - 1/2, j), shape (nf, nx + 1, ny); rows 0 and nx are the
  rigid outer boundary and are never written;
- ``qy[f, i, j]``  y velocity at (i, j - 1/2), shape (nf, nx, ny + 1); columns 0 and ny rigid;
- ``psx[f, i, j]`` x part of the split pressure inside the PML (only border cells touched).

Field 0 carries the walls (rigid velocity nodes listed per row in CSR form, impedance cells
with their implicit coefficient ``beta``); field 1, if present, is the free field.

One time step is a single fused sweep over rows: row ``i`` updates ``qx`` node ``i + 1`` and
the ``qy`` nodes of row ``i`` (from the old pressure), then the pressure of row ``i`` (from
the new velocities). Rows are split into contiguous chunks, one ``prange`` iteration each;
the first row of every chunk needs the last velocity row of the previous chunk, so its
pressure is updated in a short serial second pass (one thread barrier per step). The
arithmetic per element is the same as the plain numpy twin in the tests
(``tests/mapping/simulate/fdtd/naive.py``; tested).

:func:`_run_sweeps` (the solver's default) does the same row updates with temporal
blocking: several steps per sweep over the rows along a skewed wavefront (step ``k`` of row
``t - k`` at time ``t``), so each row comes from memory once per sweep instead of once per
step; chunk boundaries are fixed up in a second parallel pass (see its docstring). Same
arithmetic, so the fields equal :func:`_run_steps`'s bit for bit (tested).

Speed: every row is split into branch-free inner loops (PML segments with per-column
coefficients and a select-style flush, interior segments with a scalar coefficient) over
contiguous row slices indexed from 0, so LLVM vectorizes them: a shifted index such as
``pr[j - 1]`` would keep numba's negative-index wrap-around check in the loop, and a Python
``0.0`` assigned to a float32 value would promote the loop to float64 (``zero`` is passed
in the field dtype instead). This took the kernel from ~0.4 to ~1.2 G field-cell updates/s
on one thread (float32, 500^2, ``benchmarks/fdtd.py``). The row helpers are inlined at the
numba IR level (``inline="always"``): the calls with their dozens of array arguments cost
~25 % of the time per row otherwise (measured, paper domain, one thread: 1.22 -> 1.60 G).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numba import njit, prange

from mapping.numba_config import NUMBA_FLAGS, PARALLEL


class _Fields(NamedTuple):
    """The staggered fields (layout in the module notes), updated in place."""

    p: np.ndarray  # (nf, nx, ny) pressure + offset
    qx: np.ndarray  # (nf, nx + 1, ny)
    qy: np.ndarray  # (nf, nx, ny + 1)
    psx: np.ndarray  # (nf, nx, ny) x part of the split pressure in the PML


class _Coefficients(NamedTuple):
    """Update coefficients of eqs. 9-11 with the graded PML (``FdtdCoefficients``)."""

    aqx: np.ndarray  # (nx + 1,) velocity decay and gain along x
    bqx: np.ndarray
    aqy: np.ndarray  # (ny + 1,)
    bqy: np.ndarray
    apx: np.ndarray  # (nx,) split-pressure decay and gain
    bpx: np.ndarray
    apy: np.ndarray  # (ny,)
    bpy: np.ndarray
    kp: Any  # interior pressure gain rho c^2 dt / dx, in the field dtype
    npml: int  # PML thickness in cells


class _Walls(NamedTuple):
    """Walls of field 0 and the storage constants."""

    wx_ptr: np.ndarray  # rigid qx nodes, CSR by row
    wx_col: np.ndarray
    wy_ptr: np.ndarray  # rigid qy nodes, CSR by row
    wy_col: np.ndarray
    imp_ptr: np.ndarray  # impedance cells, CSR by row
    imp_col: np.ndarray
    imp_beta: np.ndarray  # their implicit coefficient
    imp_buf: np.ndarray  # scratch: their pressure before the update
    offset: Any  # pressure storage offset, field dtype
    flush: Any  # values below this are flushed to 0 in the PML, field dtype


class _Drive(NamedTuple):
    """Source and receiver of every step n: bilinear stencils (n, 4) and the source signal."""

    src_i: np.ndarray
    src_j: np.ndarray
    src_w: np.ndarray
    src_g: np.ndarray  # (n,)
    rx_i: np.ndarray
    rx_j: np.ndarray
    rx_w: np.ndarray


@njit(inline="always", **NUMBA_FLAGS)
def _qx_plain(row, p0, p1, b):  # pragma: no cover - numba
    for j in range(row.shape[0]):
        row[j] = row[j] - b * (p1[j] - p0[j])


@njit(inline="always", **NUMBA_FLAGS)
def _qx_damped(row, p0, p1, a, b, flush, zero):  # pragma: no cover - numba
    for j in range(row.shape[0]):
        v = a * row[j] - b * (p1[j] - p0[j])
        row[j] = zero if abs(v) < flush else v


@njit(inline="always", **NUMBA_FLAGS)
def _qy_plain(row, pr, b, j0, j1):  # pragma: no cover - numba
    # row[j] for j in [j0, j1), j0 >= 1: written with offsets from 0 so that no index can be
    # negative (numba's wrap-around check would otherwise block vectorization)
    r = row[j0:j1]
    hi = pr[j0:j1]
    lo = pr[j0 - 1:j1 - 1]
    for k in range(r.shape[0]):
        r[k] = r[k] - b * (hi[k] - lo[k])


@njit(inline="always", **NUMBA_FLAGS)
def _qy_damped(row, pr, aqy, bqy, j0, j1, flush, zero):  # pragma: no cover - numba
    r = row[j0:j1]
    hi = pr[j0:j1]
    lo = pr[j0 - 1:j1 - 1]
    a = aqy[j0:j1]
    b = bqy[j0:j1]
    for k in range(r.shape[0]):
        v = a[k] * r[k] - b[k] * (hi[k] - lo[k])
        r[k] = zero if abs(v) < flush else v


@njit(inline="always", **NUMBA_FLAGS)
def _velocity_row(p, qx, qy, f, i, aqx, bqx, aqy, bqy, npml, walled,
                  wx_ptr, wx_col, wy_ptr, wy_col, flush, zero):  # pragma: no cover - numba
    nx = p.shape[1]
    ny = p.shape[2]
    if i + 1 < nx:
        a = aqx[i + 1]
        b = bqx[i + 1]
        row = qx[f, i + 1]
        if a == 1:
            _qx_plain(row, p[f, i], p[f, i + 1], b)
        else:
            _qx_damped(row, p[f, i], p[f, i + 1], a, b, flush, zero)
        if walled:
            for k in range(wx_ptr[i + 1], wx_ptr[i + 2]):
                row[wx_col[k]] = zero
    row = qy[f, i]
    pr = p[f, i]
    lo = max(min(npml, ny), 1)
    hi = min(max(ny - npml + 1, lo), ny)
    if lo > 1:
        _qy_damped(row, pr, aqy, bqy, 1, lo, flush, zero)
    if hi > lo:
        _qy_plain(row, pr, bqy[lo], lo, hi)
    if ny > hi:
        _qy_damped(row, pr, aqy, bqy, hi, ny, flush, zero)
    if walled:
        for k in range(wy_ptr[i], wy_ptr[i + 1]):
            row[wy_col[k]] = zero


@njit(inline="always", **NUMBA_FLAGS)
def _p_split(pr, sx, qx0, qx1, qyr, j0, j1, ax, bx, apy, bpy, offset, flush,
             zero):  # pragma: no cover - numba
    """Split-field PML update of pressure cells [j0, j1) of one row."""
    n = j1 - j0
    r = pr[j0:j1]
    s = sx[j0:j1]
    x0 = qx0[j0:j1]
    x1 = qx1[j0:j1]
    y0 = qyr[j0:j1]
    y1 = qyr[j0 + 1:j1 + 1]
    a = apy[j0:j1]
    b = bpy[j0:j1]
    for k in range(n):
        px = ax * s[k] - bx * (x1[k] - x0[k])
        py = a[k] * (r[k] - offset - s[k]) - b[k] * (y1[k] - y0[k])
        px = zero if abs(px) < flush else px
        py = zero if abs(py) < flush else py
        s[k] = px
        r[k] = offset + px + py


@njit(inline="always", **NUMBA_FLAGS)
def _p_plain(pr, qx0, qx1, qyr, j0, j1, kp):  # pragma: no cover - numba
    r = pr[j0:j1]
    x0 = qx0[j0:j1]
    x1 = qx1[j0:j1]
    y0 = qyr[j0:j1]
    y1 = qyr[j0 + 1:j1 + 1]
    for k in range(j1 - j0):
        r[k] = r[k] - kp * ((x1[k] - x0[k]) + (y1[k] - y0[k]))


@njit(inline="always", **NUMBA_FLAGS)
def _pressure_row(p, qx, qy, psx, f, i, apx, bpx, apy, bpy, kp, npml, walled,
                  imp_ptr, imp_col, imp_beta, imp_buf, offset, flush,
                  zero):  # pragma: no cover - numba
    nx = p.shape[1]
    ny = p.shape[2]
    pr = p[f, i]
    sx = psx[f, i]
    qx0 = qx[f, i]
    qx1 = qx[f, i + 1]
    qyr = qy[f, i]
    if walled:
        for k in range(imp_ptr[i], imp_ptr[i + 1]):
            imp_buf[k] = pr[imp_col[k]]
    ax = apx[i]
    bx = bpx[i]
    if i < npml or i >= nx - npml:
        _p_split(pr, sx, qx0, qx1, qyr, 0, ny, ax, bx, apy, bpy, offset, flush, zero)
    else:
        lo = min(npml, ny)
        hi = max(ny - npml, lo)
        if lo > 0:
            _p_split(pr, sx, qx0, qx1, qyr, 0, lo, ax, bx, apy, bpy, offset, flush, zero)
        if hi > lo:
            _p_plain(pr, qx0, qx1, qyr, lo, hi, kp)
        if ny > hi:
            _p_split(pr, sx, qx0, qx1, qyr, hi, ny, ax, bx, apy, bpy, offset, flush, zero)
    if walled:
        for k in range(imp_ptr[i], imp_ptr[i + 1]):
            c = imp_col[k]
            beta = imp_beta[k]
            pr[c] = offset + ((pr[c] - offset) - beta * (imp_buf[k] - offset)) / (1.0 + beta)


@njit(inline="always", **NUMBA_FLAGS)
def _inject_and_receive(p, n, src_i, src_j, src_w, src_g, rx_i, rx_j, rx_w, out,
                        offset):  # pragma: no cover - numba
    nf = p.shape[0]
    for f in range(nf):
        for k in range(4):
            p[f, src_i[n, k], src_j[n, k]] += src_w[n, k] * src_g[n]
        acc = 0.0
        for k in range(4):
            acc += rx_w[n, k] * (p[f, rx_i[n, k], rx_j[n, k]] - offset)
        out[n, f] = acc


@njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _run_steps(fields, coef, walls, drive, out, n_chunks):  # pragma: no cover - numba
    """Advance ``drive.src_g.size`` steps: the fused sweep (a parallel pass over row chunks
    and a serial pass over the chunks' first rows), then the source and receiver of that
    step; receiver pressure into ``out`` (n, n_fields)."""
    p, qx, qy, psx = fields
    aqx, bqx, aqy, bqy, apx, bpx, apy, bpy, kp, npml = coef
    wx_ptr, wx_col, wy_ptr, wy_col, imp_ptr, imp_col, imp_beta, imp_buf, offset, flush = walls
    src_i, src_j, src_w, src_g, rx_i, rx_j, rx_w = drive
    nf = p.shape[0]
    nx = p.shape[1]
    zero = flush - flush  # in the field dtype (a Python 0.0 would promote to float64)
    for n in range(src_g.shape[0]):
        for c in prange(n_chunks):
            s = (c * nx) // n_chunks
            e = ((c + 1) * nx) // n_chunks
            for i in range(s, e):
                for f in range(nf):
                    walled = f == 0
                    _velocity_row(p, qx, qy, f, i, aqx, bqx, aqy, bqy, npml, walled,
                                  wx_ptr, wx_col, wy_ptr, wy_col, flush, zero)
                    if i > s:
                        _pressure_row(p, qx, qy, psx, f, i, apx, bpx, apy, bpy, kp, npml,
                                      walled, imp_ptr, imp_col, imp_beta, imp_buf, offset,
                                      flush, zero)
        for c in range(n_chunks):  # serial: a few rows, and one barrier per step fewer
            s = (c * nx) // n_chunks
            e = ((c + 1) * nx) // n_chunks
            if e > s:
                for f in range(nf):
                    _pressure_row(p, qx, qy, psx, f, s, apx, bpx, apy, bpy, kp, npml, f == 0,
                                  imp_ptr, imp_col, imp_beta, imp_buf, offset, flush, zero)
        _inject_and_receive(p, n, src_i, src_j, src_w, src_g, rx_i, rx_j, rx_w, out, offset)


# ---- temporal blocking: several steps per sweep over the rows --------------------------------
@njit(inline="always", **NUMBA_FLAGS)
def _velocity_rows(p, qx, qy, i, aqx, bqx, aqy, bqy, npml, wx_ptr, wx_col, wy_ptr, wy_col,
                   flush, zero):  # pragma: no cover - numba
    """V(i): ``qx`` node ``i + 1`` and the ``qy`` nodes of row ``i`` of every field."""
    for f in range(p.shape[0]):
        _velocity_row(p, qx, qy, f, i, aqx, bqx, aqy, bqy, npml, f == 0,
                      wx_ptr, wx_col, wy_ptr, wy_col, flush, zero)


@njit(inline="always", **NUMBA_FLAGS)
def _pressure_rows(p, qx, qy, psx, i, n, apx, bpx, apy, bpy, kp, npml, imp_ptr, imp_col,
                   imp_beta, imp_buf, offset, flush, zero, src_i, src_j, src_w, src_g,
                   rx_i, rx_j, rx_w, outk):  # pragma: no cover - numba
    """P(i) of step ``n`` for every field, then the part of step ``n``'s source that falls
    on row ``i`` and the receiver terms of row ``i`` (``outk[n, f, k]``, one slot per
    stencil node, so rows finished by different threads never share an output element)."""
    for f in range(p.shape[0]):
        _pressure_row(p, qx, qy, psx, f, i, apx, bpx, apy, bpy, kp, npml, f == 0,
                      imp_ptr, imp_col, imp_beta, imp_buf, offset, flush, zero)
        for k in range(4):
            if src_i[n, k] == i:
                p[f, i, src_j[n, k]] += src_w[n, k] * src_g[n]
        for k in range(4):
            if rx_i[n, k] == i:
                outk[n, f, k] = rx_w[n, k] * (p[f, i, rx_j[n, k]] - offset)


@njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _run_sweeps(fields, coef, walls, drive, outk, n_chunks, depth):  # pragma: no cover - numba
    """Advance ``drive.src_g.size`` steps, ``depth`` steps per sweep over the rows (temporal
    blocking); same arithmetic per element as :func:`_run_steps`, so the same result bit
    for bit, in a different order.

    Step ``n`` of row ``i`` is V(n, i) (velocity nodes ``qx[i + 1]``, ``qy[i]``) then
    P(n, i) (pressure ``p[i]``, then step ``n``'s source and receiver terms on row ``i``).
    V(n, i) needs P(n - 1, i) and P(n - 1, i + 1); P(n, i) needs V(n, i - 1) and V(n, i);
    those are also the only readers of what each overwrites. A sweep of ``K`` steps walks
    a skewed wavefront: at time ``t`` it does step ``k`` of row ``t - k`` for k = 0..K-1,
    so a row is read from memory once per sweep and its K updates happen while it and its
    neighbours are still in the core's cache.

    Rows are split into ``n_chunks`` contiguous chunks (one ``prange`` iteration each, at
    least ``2 depth`` rows wide). Phase 1, in parallel: each chunk does the trapezoid of
    work that needs no other chunk (step k: V on rows [s + k, e - k), P on [s + k + 1, e -
    k); the outer edges of the first and last chunk are not shrunk). Phase 2, in parallel:
    the inverted triangle left at each inner boundary b (step k: V on [b - k, b + k), P on
    [b - k, b + k + 1)), step by step. Receiver terms go to ``outk`` (n, n_fields, 4);
    the caller sums them over the last axis in node order.
    """
    p, qx, qy, psx = fields
    aqx, bqx, aqy, bqy, apx, bpx, apy, bpy, kp, npml = coef
    wx_ptr, wx_col, wy_ptr, wy_col, imp_ptr, imp_col, imp_beta, imp_buf, offset, flush = walls
    src_i, src_j, src_w, src_g, rx_i, rx_j, rx_w = drive
    nx = p.shape[1]
    zero = flush - flush  # in the field dtype (a Python 0.0 would promote to float64)
    n_total = src_g.shape[0]
    n0 = 0
    while n0 < n_total:
        kk = min(depth, n_total - n0)
        for c in prange(n_chunks):
            s = (c * nx) // n_chunks
            e = ((c + 1) * nx) // n_chunks
            shrink_lo = 0 if c == 0 else 1
            shrink_hi = 0 if c == n_chunks - 1 else 1
            for t in range(s, e + kk - 1):
                for k in range(kk):
                    i = t - k
                    v_hi = e - shrink_hi * k
                    if i < s + shrink_lo * k or i >= v_hi:
                        continue
                    _velocity_rows(p, qx, qy, i, aqx, bqx, aqy, bqy, npml, wx_ptr, wx_col,
                                   wy_ptr, wy_col, flush, zero)
                    if i >= s + shrink_lo * (k + 1):
                        _pressure_rows(p, qx, qy, psx, i, n0 + k, apx, bpx, apy, bpy, kp,
                                       npml, imp_ptr, imp_col, imp_beta, imp_buf, offset,
                                       flush, zero, src_i, src_j, src_w, src_g, rx_i, rx_j,
                                       rx_w, outk)
        for c in prange(1, n_chunks):
            b = (c * nx) // n_chunks
            for k in range(kk):
                for i in range(b - k, b + k):
                    _velocity_rows(p, qx, qy, i, aqx, bqx, aqy, bqy, npml, wx_ptr, wx_col,
                                   wy_ptr, wy_col, flush, zero)
                for i in range(b - k, b + k + 1):
                    _pressure_rows(p, qx, qy, psx, i, n0 + k, apx, bpx, apy, bpy, kp,
                                   npml, imp_ptr, imp_col, imp_beta, imp_buf, offset,
                                   flush, zero, src_i, src_j, src_w, src_g, rx_i, rx_j,
                                   rx_w, outk)
        n0 += kk
