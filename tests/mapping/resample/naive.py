"""Slow numpy twin of the kernel of :mod:`mapping.resample` (tests only).

:func:`resample_numpy` sums ``x[n] h(t fs - n)`` over every input sample for every output
time, with the Kaiser-windowed sinc evaluated exactly (``numpy.i0``), no table.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def resample_numpy(x: NDArray[np.float64], fs_in_hz: float, t_out_s: NDArray[np.float64],
                   cutoff_hz: float, half_taps: int, kaiser_beta: float) -> NDArray[np.float64]:
    """``y(t) = sum_n x[n] h(t fs - n)``, ``h`` the windowed sinc, over all n (O(N M))."""
    ratio = 2.0 * cutoff_hz / fs_in_hz
    u = np.asarray(t_out_s, dtype=np.float64).ravel()[:, None] * fs_in_hz - np.arange(x.size)
    # the kernel's taps: the 2 half_taps inputs with -half_taps <= t fs - n < half_taps
    inside = (u >= -half_taps) & (u < half_taps)
    r = np.where(inside, u / half_taps, 1.0)
    window = np.i0(kaiser_beta * np.sqrt(1.0 - r * r)) / np.i0(kaiser_beta)
    h = np.where(inside, ratio * np.sinc(ratio * u) * window, 0.0)
    return np.asarray((h @ x).reshape(np.shape(t_out_s)), dtype=np.float64)
