"""numba kernels of :mod:`mapping.heatmap` (private; imported only by
``mapping/heatmap/_resampling.py``, the resampling stage of the heat map).

``_spectral_bank`` takes its inputs as two records, :class:`_SpectralGrid` (the gridding
problem) and :class:`_Window` (the block samples for the window-edge corrections), built once
by ``_resampling._spectral_envelope``. The plain numpy twin of every kernel lives with the
tests (``tests/mapping/heatmap/naive.py``), which compare the two on random inputs.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from mapping.numba_config import NUMBA_FLAGS, PARALLEL


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _resample_fold(
    ext: np.ndarray,
    origin: float,
    centre: float,
    alphas: np.ndarray,
    n_periods: int,
    period: int,
    table: np.ndarray,
    out: np.ndarray,
) -> None:
    """Resample ``ext`` by each alpha about ``centre`` and fold into ``period`` samples.

    For direction d and output sample n = m * period + j (m < n_periods), the read position in
    ``ext`` is ``x = origin + centre + alphas[d] * (n - centre)``; the value there is the
    polyphase windowed-sinc interpolation ``sum_t ext[i - half + t] * table[p, t]`` with
    ``i = floor(x)``, ``p = round((x - i) * Q)``, ``Q = table.shape[0] - 1`` and
    ``half = taps // 2 - 1``; ``out[d, j]`` receives the sum over m (the fold). ``ext`` must be
    zero-padded so every read is in bounds (the wrapper guarantees it).
    """
    n_dirs = alphas.size
    taps = table.shape[1]
    q = table.shape[0] - 1
    half = taps // 2 - 1
    for d in numba.prange(n_dirs):
        a = alphas[d]
        for j in range(period):
            out[d, j] = 0.0
        for m in range(n_periods):
            for j in range(period):
                n = m * period + j
                x = origin + centre + a * (n - centre)
                i = int(math.floor(x))
                p = int(math.floor((x - i) * q + 0.5))
                base = i - half
                acc = 0.0
                for t in range(taps):
                    acc += ext[base + t] * table[p, t]
                out[d, j] += acc


class _SpectralGrid(NamedTuple):
    """Kaiser-Bessel gridding of the block spectrum (see :func:`_spectral_bank`, step 1)."""

    spec_re: np.ndarray  # Re G[j] at index pad + j, j in [-pad, nf/2 + pad)
    spec_im: np.ndarray  # Im G[j], same layout
    pad: int
    nf: int  # DFT length of the deapodized block
    taps: int  # gridding kernel length
    table: np.ndarray  # (per_unit + 1, taps) kernel samples
    per_unit: int  # table rows per unit of xi


class _Window(NamedTuple):
    """The block samples read by the window-edge corrections (:func:`_spectral_bank`, step 2)."""

    ext: np.ndarray  # zero-padded samples around the block
    origin: int  # index of block sample 0 in ext
    n_block: int  # B
    centre: float  # resampling centre c (B / 2)
    icentre: int  # time origin of the spectrum (B // 2)
    strip_step_rad: float  # see :func:`_add_strip`


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _spectral_bank(
    grid: _SpectralGrid,
    window: _Window,
    alphas: np.ndarray,
    period: int,
    conj_tx: np.ndarray,
    out: np.ndarray,
) -> None:
    """One-sided analytic cross-spectrum of every direction (see ``mapping.heatmap``).

    For direction d and q = 0..P/2, with Omega = 2 pi q / (alpha P):

    1. ``R(Omega) = sum_j G[j] phi(xi - j)``, xi = Omega nf / (2 pi), over the ``taps``
       integers j in (xi - taps/2, xi + taps/2]: Kaiser-Bessel gridding (type-2 NUFFT) of G,
       the length-``nf`` DFT of the deapodized block centred on ``icentre``.
       ``spec_re/spec_im[pad + j] = G[j]`` for j in [-pad, nf/2 + pad) (Hermitian-extended);
       ``phi(frac + taps/2 - 1 - t) = table[p, t]`` at ``frac = p / per_unit``, linearly
       interpolated between rows (frac = xi - floor(xi)).
    2. window correction: add ``r[u] exp(-i Omega (u - icentre))`` for the samples of the
       stretched window ``[ceil(c - alpha (c + 1/2)), ceil(c + alpha (B - 1/2 - c)))`` outside
       the block, subtract those of the block outside it (reads outside ``ext`` are 0);
       see :func:`_add_strip`.
    3. ``out[d, q] = R / alpha * exp(-i (2 pi q / P) (c (1 - 1/alpha) + icentre / alpha))
       * conj_tx[q]``; ``out[d, q] = 0`` for q > P / 2.

    Phasors advance by complex multiplication and are recomputed every 256 steps.
    """
    spec_re, spec_im, pad, nf = grid.spec_re, grid.spec_im, grid.pad, grid.nf
    taps, table, per_unit = grid.taps, grid.table, grid.per_unit
    ext, origin, n_block = window.ext, window.origin, window.n_block
    centre, icentre, strip_step_rad = window.centre, window.icentre, window.strip_step_rad
    n_dirs = alphas.size
    n_q = period // 2 + 1
    half = taps // 2
    for d in numba.prange(n_dirs):
        a = alphas[d]
        acc_re = np.empty(n_q)
        acc_im = np.empty(n_q)
        step_xi = nf / (a * period)
        for q in range(n_q):
            xi = q * step_xi
            fl = math.floor(xi)
            j0 = int(fl) - half + 1
            s = (xi - fl) * per_unit
            i0 = int(math.floor(s))
            f = s - i0
            sr = 0.0
            si = 0.0
            base_j = pad + j0
            for t in range(taps):
                w = table[i0, t] + f * (table[i0 + 1, t] - table[i0, t])
                sr += w * spec_re[base_j + t]
                si += w * spec_im[base_j + t]
            acc_re[q] = sr
            acc_im[q] = si
        # window correction (the stretched read window differs from the block by ~|1-a| B/2)
        lo = int(math.ceil(centre - a * (centre + 0.5)))
        hi = int(math.ceil(centre + a * (n_block - 0.5 - centre)))
        delta = 2.0 * math.pi / (a * period)
        for edge in range(2):
            if edge == 0:
                start, stop, sign = (lo, 0, 1.0) if lo < 0 else (0, lo, -1.0)
            else:
                start, stop, sign = (n_block, hi, 1.0) if hi > n_block else (hi, n_block, -1.0)
            _add_strip(acc_re, acc_im, ext, origin, start, stop, sign, icentre, delta,
                       strip_step_rad)
        base = -2.0 * math.pi / period * (centre * (1.0 - 1.0 / a) + icentre / a)
        cr = math.cos(base)
        ci = math.sin(base)
        pr = 1.0 / a
        pi_ = 0.0
        for q in range(n_q):
            if q % 256 == 0:
                pr = math.cos(base * q) / a
                pi_ = math.sin(base * q) / a
            zr = acc_re[q] * pr - acc_im[q] * pi_
            zi = acc_re[q] * pi_ + acc_im[q] * pr
            out[d, q] = complex(zr, zi) * conj_tx[q]
            pr, pi_ = pr * cr - pi_ * ci, pr * ci + pi_ * cr
        for q in range(n_q, period):
            out[d, q] = 0.0


@numba.njit(**NUMBA_FLAGS)
def _add_strip(
    acc_re: np.ndarray,
    acc_im: np.ndarray,
    ext: np.ndarray,
    origin: int,
    start: int,
    stop: int,
    sign: float,
    icentre: int,
    delta: float,
    max_step_rad: float,
) -> None:
    """``acc[q] += sign * sum_{start <= u < stop} r[u] exp(-i q delta (u - icentre))``.

    Written as ``exp(-i q delta (start - icentre)) T(q delta)`` with the short, smooth sum
    ``T(w) = sum_v r[start + v] exp(-i w v)`` (v < n_s = stop - start, ~12 terms): T is
    evaluated exactly every ``coarse`` steps of q, ``coarse = max(1, floor(max_step_rad /
    (delta n_s)))``, and linearly interpolated between (error <= max_step_rad^2 / 8 of
    sum |r|); the fast phase factor by a refreshed phasor. ``r[u] = ext[origin + u]``, 0
    outside ``ext``.
    """
    n_q = acc_re.size
    n_s = stop - start
    if n_s <= 0:
        return
    coarse = max(1, int(max_step_rad / (delta * n_s)))
    vals = np.zeros(n_s)
    for v in range(n_s):
        k = origin + start + v
        if 0 <= k < ext.size:
            vals[v] = sign * ext[k]
    n_g = (n_q - 1) // coarse + 2
    t_re = np.empty(n_g)
    t_im = np.empty(n_g)
    step = coarse * delta
    sr_step = math.cos(step)
    si_step = math.sin(step)
    cr = 1.0
    ci = 0.0
    for g in range(n_g):
        if g % 64 == 0:  # refresh the rotating phasor e^{i g step}
            cr = math.cos(g * step)
            ci = math.sin(g * step)
        pr = 1.0
        pi_ = 0.0
        sr = 0.0
        si = 0.0
        for v in range(n_s):
            sr += vals[v] * pr
            si -= vals[v] * pi_
            pr, pi_ = pr * cr - pi_ * ci, pr * ci + pi_ * cr
        t_re[g] = sr
        t_im[g] = si
        cr, ci = cr * sr_step - ci * si_step, cr * si_step + ci * sr_step
    ang = -delta * (start - icentre)
    cr = math.cos(ang)
    ci = math.sin(ang)
    pr = 1.0
    pi_ = 0.0
    for q in range(n_q):
        if q % 256 == 0:
            pr = math.cos(ang * q)
            pi_ = math.sin(ang * q)
        g = q // coarse
        f = (q - g * coarse) / coarse
        xr = t_re[g] + f * (t_re[g + 1] - t_re[g])
        xi = t_im[g] + f * (t_im[g + 1] - t_im[g])
        acc_re[q] += xr * pr - xi * pi_
        acc_im[q] += xr * pi_ + xi * pr
        pr, pi_ = pr * cr - pi_ * ci, pr * ci + pi_ * cr
