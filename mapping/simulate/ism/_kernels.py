"""numba kernels of :mod:`mapping.simulate.ism` (private; imported only by ``_render.py``).

The plain numpy twin (``render_numpy`` in ``tests/mapping/simulate/ism/naive.py``) computes the
same sum and the tests compare the two.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mapping.numba_config import NUMBA_FLAGS, PARALLEL


@numba.njit(**NUMBA_FLAGS)
def _ramp(f: float, half: float) -> float:
    """Raised-cosine step from 0 to 1 over [0.5 - half, 0.5 + half] (f in [0, 1))."""
    lo = 0.5 - half
    if f <= lo:
        return 0.0
    if f >= 0.5 + half:
        return 1.0
    return 0.5 - 0.5 * math.cos(math.pi * (f - lo) / (2.0 * half))


@numba.njit(**NUMBA_FLAGS)
def _table_value(table: np.ndarray, up: int, fine: int, pos: float) -> float:
    """4-point Lagrange interpolation of the periodic oversampled table at ``pos`` samples."""
    u = pos * up
    if u < 0.0 or u >= fine:
        u = u % fine
    i = math.floor(u)
    f = u - i
    k = int(i) + 2
    wm1 = -f * (f - 1.0) * (f - 2.0) / 6.0
    w0 = (f + 1.0) * (f - 1.0) * (f - 2.0) / 2.0
    w1 = -(f + 1.0) * f * (f - 2.0) / 2.0
    w2 = (f + 1.0) * f * (f - 1.0) / 6.0
    return wm1 * table[k - 1] + w0 * table[k] + w1 * table[k + 1] + w2 * table[k + 2]


@numba.njit(**NUMBA_FLAGS)
def _sinc_value(period: np.ndarray, half_taps: int, pos: float) -> float:
    """Blackman-windowed sinc interpolation of the periodic samples at ``pos`` samples."""
    p = period.size
    i0 = int(math.floor(pos))
    frac = pos - i0
    acc = 0.0
    for m in range(-half_taps + 1, half_taps + 1):
        x = frac - m
        if x == 0.0:
            s = 1.0
        else:
            s = math.sin(math.pi * x) / (math.pi * x)
        w = 0.42 + 0.5 * math.cos(math.pi * x / half_taps) + 0.08 * math.cos(
            2.0 * math.pi * x / half_taps
        )
        acc += period[(i0 + m) % p] * s * w
    return acc


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _render(
    start_sample: int,
    fs: float,
    c: float,
    spread_power: float,
    tau: np.ndarray,
    dtau: np.ndarray,
    tau_first_node: int,
    tau_step_s: float,
    gain: np.ndarray,
    gain_first_node: int,
    gain_step_s: float,
    fade_half: float,
    table: np.ndarray,
    up: int,
    period: np.ndarray,
    half_taps: int,
    out: np.ndarray,
) -> None:
    """Sum of ``gain * (c tau)**-spread_power * s(t - tau)`` over paths, per output sample.

    ``tau``/``dtau`` (n_paths, n_nodes) are the retarded delay and its time derivative on
    nodes ``(tau_first_node + j) * tau_step_s`` (cubic Hermite in between); ``gain``
    (n_paths, n_gain_nodes) on nodes ``(gain_first_node + j) * gain_step_s`` with a raised
    cosine of half-width ``fade_half`` (fraction of a step) where neighbours differ. The
    signal is the oversampled ``table`` (``half_taps == 0``) or windowed-sinc interpolation
    of ``period`` (``half_taps > 0``). Sample n is taken at ``(start_sample + n) / fs``.
    """
    n_paths = tau.shape[0]
    p = period.size
    fine = p * up
    for n in numba.prange(out.size):
        absn = start_sample + n
        t = absn / fs
        ph = float(absn % p)
        ut = t / tau_step_s - tau_first_node
        kt = int(math.floor(ut))
        ft = ut - kt
        ug = t / gain_step_s - gain_first_node
        kg = int(math.floor(ug))
        fg = ug - kg
        h00 = (1.0 + 2.0 * ft) * (1.0 - ft) * (1.0 - ft)
        h10 = ft * (1.0 - ft) * (1.0 - ft)
        h01 = ft * ft * (3.0 - 2.0 * ft)
        h11 = ft * ft * (ft - 1.0)
        acc = 0.0
        for i in range(n_paths):
            g0 = gain[i, kg]
            g1 = gain[i, kg + 1]
            if g0 == 0.0 and g1 == 0.0:
                continue
            g = g0
            if g1 != g0:
                g = g0 + (g1 - g0) * _ramp(fg, fade_half)
            d = (
                h00 * tau[i, kt]
                + h10 * tau_step_s * dtau[i, kt]
                + h01 * tau[i, kt + 1]
                + h11 * tau_step_s * dtau[i, kt + 1]
            )
            if spread_power == 1.0:
                amp = 1.0 / (c * d)
            else:
                amp = (c * d) ** (-spread_power)
            pos = ph - d * fs
            if half_taps > 0:
                v = _sinc_value(period, half_taps, pos)
            else:
                v = _table_value(table, up, fine, pos)
            acc += g * amp * v
        out[n] = acc
