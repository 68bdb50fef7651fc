"""Slow, plain numpy twins of the localization kernels, used only by the tests.

Each twin is the obviously correct version of a numba kernel (the house rule of
stumpy's ``tests/naive.py``); the tests compare the two on random inputs and edge cases.
The sensor model's twins are in ``tests/localization/sensor/naive.py``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def systematic_resample_numpy(weights: NDArray[np.float64], u0: float, n_out: int
                              ) -> NDArray[np.int64]:
    """Twin of :func:`localization.resampling.systematic_resample_u0`: the pointers
    ``(u0 + i) / n_out`` located in the CDF of the normalized weights."""
    w = np.ascontiguousarray(weights, dtype=np.float64)
    w = w / w.sum()
    cdf = np.cumsum(w)
    u = (u0 + np.arange(n_out)) / n_out
    idx = np.searchsorted(cdf, u, side="right")
    return np.minimum(idx, w.shape[0] - 1).astype(np.int64)
