"""numba kernels of the resamplers; imported only by :mod:`localization.resampling`.

Each kernel's slow, plain numpy twin lives with the tests (``tests/localization/naive.py``),
which compare the two.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from mapping.numba_config import NUMBA_FLAGS


@numba.njit(**NUMBA_FLAGS)
def _systematic_kernel(
    weights: NDArray[np.float64], u0: float, out: NDArray[np.int64]
) -> None:
    """Systematic resampling: pointers ``(u0 + i) / n`` walked along the weights' CDF.

    ``weights`` sum to 1; ``u0`` is one uniform draw in [0, 1); ``out`` gets n indices in
    non-decreasing order. Particle ``i`` is drawn ``floor(n w_i)`` or ``ceil(n w_i)`` times.
    """
    n_out = out.shape[0]
    n_in = weights.shape[0]
    cum = weights[0]
    j = 0
    for i in range(n_out):
        u = (u0 + i) / n_out
        while u >= cum and j < n_in - 1:
            j += 1
            cum += weights[j]
        out[i] = j


def systematic(weights: NDArray[np.float64], u0: float, n_out: int) -> NDArray[np.int64]:
    """Allocate the output and run :func:`_systematic_kernel`."""
    out = np.empty(n_out, dtype=np.int64)
    _systematic_kernel(weights, u0, out)
    return out
