"""numba kernel of :mod:`mapping.walls` (private; imported only by ``_peaks``).

``_local_maxima`` finds the cells of a heat map that are the largest of their window and
above a threshold, the same cells as ``H >= scipy.ndimage.maximum_filter(H, size,
mode=("nearest", "wrap"))`` and ``H > thr`` (its numpy twin, in
``tests/mapping/walls/naive.py``), but looks only at the cells above the threshold: a
block's heat map has a few hundred of its ~40 000 cells there, and the full filter was
about half the cost of reading the block's peaks.
"""

from __future__ import annotations

import numba
import numpy as np

from mapping.numba_config import NUMBA_FLAGS


@numba.njit(**NUMBA_FLAGS)
def _local_maxima(H: np.ndarray, thr: float, angle_window: int,
                  range_window: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices (row-major order, as ``np.nonzero``) of the cells above
    ``thr`` that no cell of their window exceeds: rows within ``angle_window`` (clipped
    at the edges, scipy's ``nearest``), columns within ``range_window`` (wrapped)."""
    n_rows, n_cols = H.shape
    rows = np.empty(16, dtype=np.int64)
    cols = np.empty(16, dtype=np.int64)
    count = 0
    for i in range(n_rows):
        i0 = max(i - angle_window, 0)
        i1 = min(i + angle_window, n_rows - 1)
        for j in range(n_cols):
            h = H[i, j]
            if not h > thr:
                continue
            top = True
            for a in range(i0, i1 + 1):
                for d in range(-range_window, range_window + 1):
                    if H[a, (j + d) % n_cols] > h:
                        top = False
                        break
                if not top:
                    break
            if not top:
                continue
            if count == rows.size:
                rows = np.concatenate((rows, np.empty(rows.size, dtype=np.int64)))
                cols = np.concatenate((cols, np.empty(cols.size, dtype=np.int64)))
            rows[count] = i
            cols[count] = j
            count += 1
    return rows[:count].copy(), cols[:count].copy()
