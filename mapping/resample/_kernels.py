"""numba kernel of :mod:`mapping.resample` (private; imported only by ``__init__.py``).

The plain numpy twin (``resample_numpy`` in ``tests/mapping/resample/naive.py``) evaluates the
same windowed sinc exactly (no table) and the tests compare the two.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mapping.numba_config import NUMBA_FLAGS, PARALLEL


@numba.njit(parallel=PARALLEL, **NUMBA_FLAGS)
def _resample(
    x: np.ndarray,
    pos: np.ndarray,
    table: np.ndarray,
    oversample: int,
    half_taps: int,
    out: np.ndarray,
) -> None:
    """``out[i] = sum_n x[n] h(pos[i] - n)`` over the ``2 half_taps`` inputs nearest ``pos[i]``.

    ``pos`` are output times in input samples; ``table`` holds the even kernel ``h`` at
    distances ``k / oversample`` (k = 0 .. half_taps * oversample, plus one trailing zero),
    linearly interpolated in between. Inputs outside ``0 .. x.size - 1`` count as zero.
    """
    n_in = x.size
    for i in numba.prange(pos.size):
        p = pos[i]
        i0 = int(math.floor(p))
        frac = p - i0
        lo = max(-half_taps + 1, -i0)
        hi = min(half_taps, n_in - 1 - i0)
        acc = 0.0
        for m in range(lo, hi + 1):
            u = abs(frac - m) * oversample
            k = int(u)
            f = u - k
            acc += x[i0 + m] * (table[k] + f * (table[k + 1] - table[k]))
        out[i] = acc
