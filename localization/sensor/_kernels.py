"""numba kernels of the sensor model; imported only by :mod:`localization.sensor`.

The kernels read small records instead of long positional lists: :class:`_ScoreTables`
(the map's lookup tables, built once per :class:`~localization.sensor.SensorTables`),
:class:`_Particles` (the poses located on the map) and :class:`_Entries` (the kept
measurement entries). Each kernel's slow, plain numpy twin lives with the tests
(``tests/localization/sensor/naive.py``), which compare the two.

The G models' kernels are serial on purpose (``nogil``, no ``prange``): one filter update is
a few milliseconds, the HTTP service runs many sessions' updates in parallel threads, and on
this shared 2-core machine a parallel region waiting for its second thread cost 10-20 ms per
call (measured: 2.5 ms per update with one thread vs 18-25 ms with two under load). The echo
model's scoring has a parallel twin (:func:`_echo_kernel_parallel`), used where its forward
model runs in parallel too (a particle set, not the few poses of a refinement): its update is
several times the G model's, mostly these two kernels.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from mapping.numba_config import NUMBA_FLAGS, PARALLEL


class _ScoreTables(NamedTuple):
    """The lookup tables the kernels read (see :class:`~localization.sensor.SensorTables`).

    ``g`` is the padded, flattened G with row length ``nx_pad``; ``cos_tab``/``sin_tab``
    (n_headings, n_angles) the direction cosines; ``r_cells`` (n_r,) the range bins in
    cells; ``s1``/``s2`` the per-cell sum and sum of squares of the ``n_samp`` polar
    samples; ``ring`` (n_cells, n_r) the per-cell ring sums of the range model.
    """

    g: NDArray[np.float32]
    nx_pad: int
    cos_tab: NDArray[np.float64]
    sin_tab: NDArray[np.float64]
    r_cells: NDArray[np.float64]
    s1: NDArray[np.float64]
    s2: NDArray[np.float64]
    ring: NDArray[np.float32]
    n_samp: int


class _Particles(NamedTuple):
    """Poses located on the map: padded flat index ``base`` of the nearest cell, offset
    ``(ux, uy)`` from its centre in cells (each in [-0.5, 0.5]), heading bin ``hb`` and map
    cell ``cell`` (-1: off the map)."""

    base: NDArray[np.int64]
    ux: NDArray[np.float64]
    uy: NDArray[np.float64]
    hb: NDArray[np.int64]
    cell: NDArray[np.int64]


class _Entries(NamedTuple):
    """The measurement's non-zero entries: entry ``t`` is polar sample ``(k, j)`` given as
    its range in cells ``r[t] = r_cells[k]`` and angle index ``j[t]``, with value
    ``val[t]``; ``m_mean``/``m_norm`` are the dense measurement's mean and centred norm."""

    r: NDArray[np.float64]
    j: NDArray[np.int64]
    val: NDArray[np.float64]
    m_mean: float
    m_norm: float


@numba.njit(**NUMBA_FLAGS)
def _score_kernel(
    tab: _ScoreTables, p: _Particles, e: _Entries, out: NDArray[np.float64]
) -> None:
    """Pearson correlation of a sparse measurement with the polar samples of ``tab.g``.

    Particle i sits ``(p.ux[i], p.uy[i])`` cells from the centre of the cell with padded
    flat index ``p.base[i]``, with heading bin ``h = p.hb[i]``; polar sample
    ``s = k * n_angles + j`` is the cell nearest to that point plus
    ``r_k (cos_tab[h, j], sin_tab[h, j])`` (offsets rounded relative to the cell, so a
    cell centre reproduces the heading-0 table exactly). Only the measurement's non-zero
    entries ``e`` enter, so the cross term is a sparse dot product (each entry's range and
    angle index are split once per measurement by :func:`score`: an integer division per
    entry and particle cost more than half of the kernel's time). The sample sum and sum
    of squares come from the per-cell tables ``s1`` and ``s2``. ``p.cell[i] < 0`` marks a
    particle off the map (``out = nan``).
    """
    g = tab.g
    nx_pad = tab.nx_pad
    s1 = tab.s1
    s2 = tab.s2
    n_samp = tab.n_samp
    r_entry = e.r
    j_entry = e.j
    val = e.val
    m_mean = e.m_mean
    m_norm = e.m_norm
    for i in range(p.base.shape[0]):
        c = p.cell[i]
        if c < 0:
            out[i] = np.nan
            continue
        h = p.hb[i]
        b = p.base[i]
        x = p.ux[i] + 0.5
        y = p.uy[i] + 0.5
        cos_h = tab.cos_tab[h]
        sin_h = tab.sin_tab[h]
        dot = 0.0
        for t in range(val.shape[0]):
            j = j_entry[t]
            r = r_entry[t]
            dx = int(math.floor(r * cos_h[j] + x))
            dy = int(math.floor(r * sin_h[j] + y))
            dot += val[t] * g[b + dy * nx_pad + dx]
        var = s2[c] - s1[c] * s1[c] / n_samp
        out[i] = (dot - m_mean * s1[c]) / (m_norm * math.sqrt(var)) if var > 1e-18 else 0.0


def score(tab: _ScoreTables, p: _Particles, idx: NDArray[np.int64], val: NDArray[np.float64],
          m_mean: float, m_norm: float) -> NDArray[np.float64]:
    """Split the measurement entries ``idx`` (flat polar indices) into range and angle once,
    allocate the output and run :func:`_score_kernel`."""
    n_angles = tab.cos_tab.shape[1]
    e = _Entries(r=np.ascontiguousarray(tab.r_cells[idx // n_angles], dtype=np.float64),
                 j=np.ascontiguousarray(idx % n_angles, dtype=np.int64),
                 val=np.ascontiguousarray(val, dtype=np.float64),
                 m_mean=m_mean, m_norm=m_norm)
    out = np.empty(p.base.shape[0], dtype=np.float64)
    _score_kernel(tab, p, e, out)
    return out


@numba.njit(**NUMBA_FLAGS)
def _range_kernel(
    ring: NDArray[np.float32], cell: NDArray[np.int64], m0: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Pearson correlation of the range profile ``m0`` (zero mean, unit norm) with the ring
    sums ``ring[cell[i]]`` of G around each particle's cell (``cell < 0``: nan)."""
    n_r = ring.shape[1]
    for i in range(cell.shape[0]):
        c = cell[i]
        if c < 0:
            out[i] = np.nan
            continue
        s_mp = 0.0
        s_p = 0.0
        s_pp = 0.0
        for k in range(n_r):
            p = float(ring[c, k])
            s_mp += m0[k] * p
            s_p += p
            s_pp += p * p
        var = s_pp - s_p * s_p / n_r
        out[i] = s_mp / math.sqrt(var) if var > 1e-18 else 0.0


def score_range(ring: NDArray[np.float32], cell: NDArray[np.int64],
                m0: NDArray[np.float64]) -> NDArray[np.float64]:
    """Allocate the output and run :func:`_range_kernel`."""
    out = np.empty(cell.shape[0], dtype=np.float64)
    _range_kernel(ring, cell, m0, out)
    return out


class _EchoPeaks(NamedTuple):
    """The measured echo peaks of one block: range (m), Doppler cosine, weight and level of
    each (``la``: natural log of the peak's heat-map value relative to the block's strongest),
    and the kernel widths (``sig_r`` m, ``sig_c`` cosine; ``use_cos`` False: range only)."""

    r: NDArray[np.float64]
    c: NDArray[np.float64]
    w: NDArray[np.float64]
    la: NDArray[np.float64]
    sig_r: float
    sig_c: float
    use_cos: bool


class _EchoTerms(NamedTuple):
    """The echo model's constants: clutter share ``eps`` of a measured peak no predicted echo
    explains, detection probability ``p_max`` of a predicted echo at full relative level
    (ramping from 0 at ``rel_lo`` to ``p_max`` at ``rel_hi`` of the pose's strongest echo),
    the range window ``[r_min, r_max]`` in which peaks are read, and the log-level tolerance
    ``sig_a`` of a matched peak (0: levels not compared)."""

    eps: float
    p_max: float
    rel_lo: float
    rel_hi: float
    r_min: float
    r_max: float
    sig_a: float = 0.0


@numba.njit(**NUMBA_FLAGS)
def _nz(x: float) -> float:
    """``x`` as ``np.nan_to_num`` gives it: NaN 0, +-inf the largest finite float (the
    padding of an echo batch is NaN; read in the kernel, no copy of the arrays)."""
    if x != x:
        return 0.0
    if x == math.inf:
        return 1.7976931348623157e308
    if x == -math.inf:
        return -1.7976931348623157e308
    return x


class _EchoScratch(NamedTuple):
    """Work arrays of one thread of :func:`_echo_rows`, reused pose after pose: per measured
    peak the best kappa, the summed level of the echoes that make it and its level factor
    alpha, and kappa of every (peak, echo) pair."""

    best: NDArray[np.float64]
    level: NDArray[np.float64]
    alpha: NDArray[np.float64]
    kap: NDArray[np.float64]


@numba.njit(**NUMBA_FLAGS)
def _echo_scratch(n_meas: int, k: int) -> _EchoScratch:
    return _EchoScratch(np.empty(n_meas), np.empty(n_meas), np.empty(n_meas),
                        np.zeros((n_meas, k)))


#: Poses per work item of :func:`_echo_kernel_parallel` (each item allocates its scratch once).
ECHO_CHUNK = 64


@numba.njit(**NUMBA_FLAGS)
def _echo_kernel(
    count: NDArray[np.int64], pr: NDArray[np.float64], pc: NDArray[np.float64],
    pa: NDArray[np.float64], ps: NDArray[np.float64], pl: NDArray[np.float64],
    m: _EchoPeaks, t: _EchoTerms, out: NDArray[np.float64],
) -> None:
    """Echo log-likelihood of each pose, and how much each pose explains.

    Pose i predicts ``count[i]`` echoes (range ``pr``, Doppler cosine ``pc``, detection
    level ``pa``, the map's range uncertainty ``ps`` in m, amplitude ``pl`` once heard); the
    block measured peaks ``m``. With ``kappa_jk = exp(-(dr/s_k)^2/2 - (dc/sig_c)^2/2)``,
    ``s_k = sqrt(sig_r^2 + ps_k^2)`` (the cosine term only when ``m.use_cos``):

        ll = sum_j w_j log(eps + (1 - eps) alpha_j max_k kappa_jk)    measured peaks
           + sum_k log(1 - p_k (1 - max_j alpha_j kappa_jk))          predicted echoes

    ``p_k`` the detection probability of echo k from its level relative to the pose's
    strongest echo in the window. ``alpha_j`` compares peak j's level with the echoes that
    make it: ``L_j = sum_k kappa_jk pl_k`` (echoes closer than the resolution add up), the
    pose's gain ``g`` the mean of ``la_j - log L_j`` weighted ``w_j max_k kappa_jk``, and
    ``alpha_j = exp(-((la_j - log L_j - g) / sig_a)^2 / 2)`` where ``L_j > 0``; 1 where not,
    with fewer than two peaks or ``t.sig_a = 0``. ``out[i] = (ll, explained, heard)``: the
    weighted share of measured peaks explained (``sum w_j max_k kappa / sum w_j``) and the
    detection-weighted share of predicted echoes heard (``sum p_k max_j kappa / sum p_k``; 1
    when none is expected), both geometric (range and cosine, never the level).
    """
    sc = _echo_scratch(m.r.shape[0], pr.shape[1])
    _echo_rows(count, pr, pc, pa, ps, pl, m, t, out, 0, count.shape[0], sc)


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _echo_kernel_parallel(
    count: NDArray[np.int64], pr: NDArray[np.float64], pc: NDArray[np.float64],
    pa: NDArray[np.float64], ps: NDArray[np.float64], pl: NDArray[np.float64],
    m: _EchoPeaks, t: _EchoTerms, out: NDArray[np.float64],
) -> None:
    """:func:`_echo_kernel` spread over numba's threads in chunks of :data:`ECHO_CHUNK` poses
    (each pose's arithmetic unchanged: the same numbers bit for bit)."""
    n = count.shape[0]
    for c in numba.prange((n + ECHO_CHUNK - 1) // ECHO_CHUNK):
        sc = _echo_scratch(m.r.shape[0], pr.shape[1])
        _echo_rows(count, pr, pc, pa, ps, pl, m, t, out, c * ECHO_CHUNK,
                   min(n, (c + 1) * ECHO_CHUNK), sc)


@numba.njit(**NUMBA_FLAGS)
def _echo_rows(
    count: NDArray[np.int64], pr: NDArray[np.float64], pc: NDArray[np.float64],
    pa: NDArray[np.float64], ps: NDArray[np.float64], pl: NDArray[np.float64],
    m: _EchoPeaks, t: _EchoTerms, out: NDArray[np.float64], i0: int, i1: int,
    sc: _EchoScratch,
) -> None:
    """Rows ``i0 .. i1 - 1`` of :func:`_echo_kernel` with the work arrays ``sc``."""
    n_meas = m.r.shape[0]
    best, level, alpha, kap = sc.best, sc.level, sc.alpha, sc.kap
    w_sum = 0.0
    for j in range(n_meas):
        w_sum += m.w[j]
    log_eps = math.log(t.eps)
    levels = t.sig_a > 0.0 and n_meas >= 2
    for i in range(i0, i1):
        n_pred = count[i]
        a_max = 0.0
        for k in range(n_pred):
            a_k = _nz(pa[i, k])
            if t.r_min <= _nz(pr[i, k]) <= t.r_max and a_k > a_max:
                a_max = a_k
        for j in range(n_meas):
            best[j] = 0.0
            level[j] = 0.0
            alpha[j] = 1.0
        # geometry: every (peak, echo) pair once
        for k in range(n_pred):
            r = _nz(pr[i, k])
            c_k = _nz(pc[i, k])
            l_k = _nz(pl[i, k])
            m_k = _nz(ps[i, k])
            inside = t.r_min <= r <= t.r_max
            s_k = math.sqrt(m.sig_r * m.sig_r + m_k * m_k)
            for j in range(n_meas):
                kv = 0.0
                if inside:
                    d = (m.r[j] - r) / s_k
                    e = 0.5 * d * d
                    if m.use_cos and e < 18.0:      # most pairs are already out on range
                        dc = (m.c[j] - c_k) / m.sig_c
                        e += 0.5 * dc * dc
                    if e < 18.0:
                        kv = math.exp(-e)
                kap[j, k] = kv
                if kv > best[j]:
                    best[j] = kv
                if l_k > 0.0:
                    level[j] += kv * l_k
        # levels: each peak against the echoes that make it, after the pose's gain
        if levels:
            g_sum = 0.0
            g_w = 0.0
            for j in range(n_meas):
                if level[j] > 0.0:
                    wj = m.w[j] * best[j]
                    g_sum += wj * (m.la[j] - math.log(level[j]))
                    g_w += wj
            if g_w > 0.0:
                gain = g_sum / g_w
                for j in range(n_meas):
                    if level[j] > 0.0:
                        da = (m.la[j] - math.log(level[j]) - gain) / t.sig_a
                        alpha[j] = math.exp(-0.5 * da * da)
        ll = 0.0
        p_sum = 0.0
        heard = 0.0
        for k in range(n_pred):
            r = _nz(pr[i, k])
            if r < t.r_min or r > t.r_max:
                continue
            bk = 0.0
            bk_a = 0.0
            for j in range(n_meas):
                kv = kap[j, k]
                if kv > bk:
                    bk = kv
                if alpha[j] * kv > bk_a:
                    bk_a = alpha[j] * kv
            rel = _nz(pa[i, k]) / a_max if a_max > 0.0 else 0.0
            p = t.p_max * min(max((rel - t.rel_lo) / (t.rel_hi - t.rel_lo), 0.0), 1.0)
            ll += math.log(1.0 - p * (1.0 - bk_a))
            p_sum += p
            heard += p * bk
        explained = 0.0
        for j in range(n_meas):
            b = alpha[j] * best[j]
            ll += m.w[j] * (math.log(t.eps + (1.0 - t.eps) * b) if b > 0.0 else log_eps)
            explained += m.w[j] * best[j]
        out[i, 0] = ll
        out[i, 1] = explained / w_sum if w_sum > 0.0 else 1.0
        out[i, 2] = heard / p_sum if p_sum > 0.0 else 1.0


def score_echo(count: NDArray[np.int64], pr: NDArray[np.float64], pc: NDArray[np.float64],
               pa: NDArray[np.float64], m: _EchoPeaks, t: _EchoTerms,
               map_sigma: NDArray[np.float64] | None = None,
               amplitude: NDArray[np.float64] | None = None,
               parallel: bool = False) -> NDArray[np.float64]:
    """Allocate the (n, 3) output and run :func:`_echo_kernel` (NaN padding read as 0 by the
    kernel, as ``nan_to_num``; ``map_sigma`` None: no map uncertainty; ``amplitude`` None:
    ``pa`` is also the heard echo's amplitude; ``parallel``: over numba's threads, the same
    numbers)."""
    out = np.empty((count.shape[0], 3), dtype=np.float64)
    ps = np.zeros_like(pr) if map_sigma is None else map_sigma
    pl = pa if amplitude is None else amplitude
    kernel = _echo_kernel_parallel if parallel else _echo_kernel
    kernel(np.ascontiguousarray(count, dtype=np.int64),
           np.ascontiguousarray(pr, dtype=np.float64),
           np.ascontiguousarray(pc, dtype=np.float64),
           np.ascontiguousarray(pa, dtype=np.float64),
           np.ascontiguousarray(ps, dtype=np.float64),
           np.ascontiguousarray(pl, dtype=np.float64), m, t, out)
    return out


# ---- the map's uncertainty per predicted echo (walls maps) --------------------------------
@numba.njit(**NUMBA_FLAGS)
def _ndtr(x: float) -> float:
    """Standard normal cumulative distribution."""
    return 0.5 * math.erfc(-x / math.sqrt(2.0))


@numba.njit(**NUMBA_FLAGS)
def _bounce_point(points: NDArray[np.float64], i: int, j: int, r: int) -> tuple[float, float]:
    """Bounce r of echo (i, j); a NaN coordinate (padding) counts as 0, as ``nan_to_num``."""
    px, py = points[i, j, r, 0], points[i, j, r, 1]
    return (0.0 if math.isnan(px) else px), (0.0 if math.isnan(py) else py)


@numba.njit(**NUMBA_FLAGS)
def _end_weights_row(seg: NDArray[np.float64], end_sigma: NDArray[np.float64],
                     wall_idx: NDArray[np.int64], points: NDArray[np.float64],
                     out: NDArray[np.float64], i: int) -> None:
    """Row i of :func:`_end_weights_kernel`."""
    for j in range(wall_idx.shape[1]):
        w = 1.0
        for r in range(wall_idx.shape[2]):
            wi = wall_idx[i, j, r]
            if wi < 0:
                continue
            ax, ay = seg[wi, 0, 0], seg[wi, 0, 1]
            bx, by = seg[wi, 1, 0], seg[wi, 1, 1]
            length = max(math.hypot(bx - ax, by - ay), 1e-12)
            ux, uy = (bx - ax) / length, (by - ay) / length
            px, py = _bounce_point(points, i, j, r)
            if end_sigma[wi, 0] > 0:
                w *= _ndtr(((px - ax) * ux + (py - ay) * uy) / end_sigma[wi, 0])
            if end_sigma[wi, 1] > 0:
                w *= _ndtr(((bx - px) * ux + (by - py) * uy) / end_sigma[wi, 1])
        out[i, j] = w


@numba.njit(**NUMBA_FLAGS)
def _end_weights_kernel(seg: NDArray[np.float64], end_sigma: NDArray[np.float64],
                        wall_idx: NDArray[np.int64], points: NDArray[np.float64],
                        out: NDArray[np.float64]) -> None:
    """``out[i, j]`` = product over the bounces of echo (i, j) of ``Phi(s0 / sigma0)
    Phi(s1 / sigma1)`` (see ``_tables.end_weights``); a NaN point counts as the origin."""
    for i in range(wall_idx.shape[0]):
        _end_weights_row(seg, end_sigma, wall_idx, points, out, i)


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _end_weights_kernel_parallel(seg: NDArray[np.float64], end_sigma: NDArray[np.float64],
                                 wall_idx: NDArray[np.int64], points: NDArray[np.float64],
                                 out: NDArray[np.float64]) -> None:
    """:func:`_end_weights_kernel` over numba's threads (the same numbers)."""
    for i in numba.prange(wall_idx.shape[0]):
        _end_weights_row(seg, end_sigma, wall_idx, points, out, i)


@numba.njit(**NUMBA_FLAGS)
def _map_sigma_row(seg: NDArray[np.float64], wall_sigma: NDArray[np.float64],
                   wall_idx: NDArray[np.int64], points: NDArray[np.float64],
                   out: NDArray[np.float64], i: int) -> None:
    """Row i of :func:`_map_sigma_kernel`."""
    for j in range(wall_idx.shape[1]):
        var = 0.0
        for r in range(wall_idx.shape[2]):
            wi = wall_idx[i, j, r]
            if wi < 0:
                continue
            mx = 0.5 * (seg[wi, 0, 0] + seg[wi, 1, 0])
            my = 0.5 * (seg[wi, 0, 1] + seg[wi, 1, 1])
            px, py = _bounce_point(points, i, j, r)
            along = math.hypot(px - mx, py - my)
            var += wall_sigma[wi, 0] ** 2 + (along * wall_sigma[wi, 1]) ** 2
        out[i, j] = math.sqrt(var)


@numba.njit(**NUMBA_FLAGS)
def _map_sigma_kernel(seg: NDArray[np.float64], wall_sigma: NDArray[np.float64],
                      wall_idx: NDArray[np.int64], points: NDArray[np.float64],
                      out: NDArray[np.float64]) -> None:
    """``out[i, j]`` = sqrt of the sum over the bounces of echo (i, j) of ``o**2 + (s a)**2``
    (see ``_echo.map_range_sigma``); a NaN point counts as the origin."""
    for i in range(wall_idx.shape[0]):
        _map_sigma_row(seg, wall_sigma, wall_idx, points, out, i)


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _map_sigma_kernel_parallel(seg: NDArray[np.float64], wall_sigma: NDArray[np.float64],
                               wall_idx: NDArray[np.int64], points: NDArray[np.float64],
                               out: NDArray[np.float64]) -> None:
    """:func:`_map_sigma_kernel` over numba's threads (the same numbers)."""
    for i in numba.prange(wall_idx.shape[0]):
        _map_sigma_row(seg, wall_sigma, wall_idx, points, out, i)


def end_weight_rows(seg: NDArray[np.float64], end_sigma: NDArray[np.float64],
                    wall_idx: NDArray[np.int64], points: NDArray[np.float64],
                    parallel: bool = False) -> NDArray[np.float64]:
    """:func:`_end_weights_kernel` over (n, k, K) bounces (any leading shape of wall_idx[..., K]
    is flattened to rows; ``parallel``: over numba's threads, the same numbers)."""
    lead = wall_idx.shape[:-1]
    if wall_idx.ndim == 3:   # (n, k, K) as an echo batch gives it: read in place, no copy
        idx = np.asarray(wall_idx, dtype=np.int64)
        pts = np.asarray(points, dtype=np.float64)
    else:
        idx = np.ascontiguousarray(wall_idx.reshape(-1, 1, wall_idx.shape[-1]), dtype=np.int64)
        pts = np.ascontiguousarray(points.reshape(-1, 1, points.shape[-2], 2), dtype=np.float64)
    out = np.empty(idx.shape[:2])
    kernel = _end_weights_kernel_parallel if parallel else _end_weights_kernel
    kernel(np.ascontiguousarray(seg, dtype=np.float64),
           np.ascontiguousarray(end_sigma, dtype=np.float64), idx, pts, out)
    return out.reshape(lead)


def map_sigma_rows(seg: NDArray[np.float64], wall_sigma: NDArray[np.float64],
                   wall_idx: NDArray[np.int64], points: NDArray[np.float64],
                   parallel: bool = False) -> NDArray[np.float64]:
    """:func:`_map_sigma_kernel` over (n, k, K) bounces (``parallel``: over numba's threads,
    the same numbers)."""
    out = np.empty(wall_idx.shape[:2])
    kernel = _map_sigma_kernel_parallel if parallel else _map_sigma_kernel
    kernel(np.ascontiguousarray(seg, dtype=np.float64),
           np.ascontiguousarray(wall_sigma, dtype=np.float64),
           np.asarray(wall_idx, dtype=np.int64),      # an echo batch's slice: read in place
           np.asarray(points, dtype=np.float64), out)
    return out


@numba.njit(**NUMBA_FLAGS)
def _faces_row(seg: NDArray[np.float64], side: NDArray[np.int64], poses: NDArray[np.float64],
               count: NDArray[np.int64], wall_idx: NDArray[np.int64],
               points: NDArray[np.float64], tol_m: float, out: NDArray[np.bool_],
               i: int) -> None:
    """Row i of :func:`_faces_kernel`."""
    for j in range(wall_idx.shape[1]):
        ok = j < count[i]
        qx, qy = poses[i, 0], poses[i, 1]
        for r in range(wall_idx.shape[2]):
            if not ok:
                break
            wi = wall_idx[i, j, r]
            if wi < 0:
                break
            if side[wi] != 0:
                ax, ay = seg[wi, 0, 0], seg[wi, 0, 1]
                dx, dy = seg[wi, 1, 0] - ax, seg[wi, 1, 1] - ay
                length = max(math.hypot(dx, dy), 1e-12)
                off = (dx * (qy - ay) - dy * (qx - ax)) / length
                if off * side[wi] < -tol_m:
                    ok = False
            qx, qy = _bounce_point(points, i, j, r)
        out[i, j] = ok


@numba.njit(**NUMBA_FLAGS)
def _faces_kernel(seg: NDArray[np.float64], side: NDArray[np.int64], poses: NDArray[np.float64],
                  count: NDArray[np.int64], wall_idx: NDArray[np.int64],
                  points: NDArray[np.float64], tol_m: float, out: NDArray[np.bool_]) -> None:
    """``out[i, j]``: echo j of pose i meets every wall it bounces on from a side the wall was
    heard from (``side`` +1 left of a -> b, -1 right, 0 both): the sound arrives at bounce r
    from bounce r - 1 (the pose for the first), at most ``tol_m`` behind the wall's line.
    False for padding (``j >= count[i]``)."""
    for i in range(wall_idx.shape[0]):
        _faces_row(seg, side, poses, count, wall_idx, points, tol_m, out, i)


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _faces_kernel_parallel(seg: NDArray[np.float64], side: NDArray[np.int64],
                           poses: NDArray[np.float64], count: NDArray[np.int64],
                           wall_idx: NDArray[np.int64], points: NDArray[np.float64],
                           tol_m: float, out: NDArray[np.bool_]) -> None:
    """:func:`_faces_kernel` over numba's threads (the same numbers)."""
    for i in numba.prange(wall_idx.shape[0]):
        _faces_row(seg, side, poses, count, wall_idx, points, tol_m, out, i)


def face_rows(seg: NDArray[np.float64], side: NDArray[np.int64], poses: NDArray[np.float64],
              count: NDArray[np.int64], wall_idx: NDArray[np.int64],
              points: NDArray[np.float64], tol_m: float, parallel: bool = False
              ) -> NDArray[np.bool_]:
    """:func:`_faces_kernel` over an echo batch (n, k, K) (``parallel``: over numba's
    threads, the same numbers)."""
    out = np.empty(wall_idx.shape[:2], dtype=np.bool_)
    kernel = _faces_kernel_parallel if parallel else _faces_kernel
    kernel(np.ascontiguousarray(seg, dtype=np.float64),
           np.ascontiguousarray(side, dtype=np.int64),
           np.ascontiguousarray(poses, dtype=np.float64), np.asarray(count, dtype=np.int64),
           np.asarray(wall_idx, dtype=np.int64), np.asarray(points, dtype=np.float64),
           float(tol_m), out)
    return out


@numba.njit(**NUMBA_FLAGS)
def _compact_row(keep: NDArray[np.bool_], f: NDArray[np.float64], order: NDArray[np.int64],
                 walls: NDArray[np.int64], points: NDArray[np.float64],
                 f_out: NDArray[np.float64], order_out: NDArray[np.int64],
                 walls_out: NDArray[np.int64], points_out: NDArray[np.float64],
                 count_out: NDArray[np.int64], i: int) -> None:
    """Row i of :func:`_compact_kernel`."""
    k = keep.shape[1]
    w = 0
    for j in range(k):
        if not keep[i, j]:
            continue
        for q in range(f.shape[0]):
            f_out[q, i, w] = f[q, i, j]
        order_out[i, w] = order[i, j]
        for r in range(walls.shape[2]):
            walls_out[i, w, r] = walls[i, j, r]
            points_out[i, w, r, 0] = points[i, j, r, 0]
            points_out[i, w, r, 1] = points[i, j, r, 1]
        w += 1
    count_out[i] = w
    for j in range(w, k):
        for q in range(f.shape[0]):
            f_out[q, i, j] = np.nan
        order_out[i, j] = 0
        for r in range(walls.shape[2]):
            walls_out[i, j, r] = -1
            points_out[i, j, r, 0] = np.nan
            points_out[i, j, r, 1] = np.nan


@numba.njit(**NUMBA_FLAGS)
def _compact_kernel(keep: NDArray[np.bool_], f: NDArray[np.float64], order: NDArray[np.int64],
                    walls: NDArray[np.int64], points: NDArray[np.float64],
                    f_out: NDArray[np.float64], order_out: NDArray[np.int64],
                    walls_out: NDArray[np.int64], points_out: NDArray[np.float64],
                    count_out: NDArray[np.int64]) -> None:
    """Each row's kept echoes (``keep`` (n, k)) moved to its front in their order, the rest
    padding (NaN floats, ``order`` 0, ``walls`` -1, NaN points): ``f`` (m, n, k) stacks the
    batch's float fields, ``walls`` / ``points`` are (n, k, K) / (n, k, K, 2)."""
    for i in range(keep.shape[0]):
        _compact_row(keep, f, order, walls, points, f_out, order_out, walls_out, points_out,
                     count_out, i)


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _compact_kernel_parallel(keep: NDArray[np.bool_], f: NDArray[np.float64],
                             order: NDArray[np.int64], walls: NDArray[np.int64],
                             points: NDArray[np.float64], f_out: NDArray[np.float64],
                             order_out: NDArray[np.int64], walls_out: NDArray[np.int64],
                             points_out: NDArray[np.float64],
                             count_out: NDArray[np.int64]) -> None:
    """:func:`_compact_kernel` over numba's threads (the same numbers)."""
    for i in numba.prange(keep.shape[0]):
        _compact_row(keep, f, order, walls, points, f_out, order_out, walls_out, points_out,
                     count_out, i)


def compact_rows(keep: NDArray[np.bool_], f: NDArray[np.float64], order: NDArray[np.int64],
                 walls: NDArray[np.int64], points: NDArray[np.float64],
                 parallel: bool = False) -> tuple[NDArray[np.int64], NDArray[np.float64],
                                                   NDArray[np.int64], NDArray[np.int64],
                                                   NDArray[np.float64]]:
    """:func:`_compact_kernel` on an echo batch's fields; returns the counts and the
    compacted ``f``, ``order``, ``walls``, ``points`` (``parallel``: over numba's threads,
    the same numbers)."""
    f_out = np.empty(f.shape, dtype=np.float64)
    order_out = np.empty(order.shape, dtype=np.int64)
    walls_out = np.empty(walls.shape, dtype=np.int64)
    points_out = np.empty(points.shape, dtype=np.float64)
    count_out = np.empty(keep.shape[0], dtype=np.int64)
    kernel = _compact_kernel_parallel if parallel else _compact_kernel
    kernel(np.ascontiguousarray(keep), np.ascontiguousarray(f, dtype=np.float64),
           np.ascontiguousarray(order, dtype=np.int64),
           np.ascontiguousarray(walls, dtype=np.int64),
           np.ascontiguousarray(points, dtype=np.float64), f_out, order_out, walls_out,
           points_out, count_out)
    return count_out, f_out, order_out, walls_out, points_out
