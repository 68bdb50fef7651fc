"""Plain numpy twin of the numba kernel of :mod:`mapping.walls` (tests only).

``local_maxima_numpy`` is what ``heatmap_peaks`` computed before the kernel: the full
``scipy.ndimage.maximum_filter`` of the heat map (rows clipped, columns wrapped) compared
with every cell.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage


def local_maxima_numpy(H: NDArray[np.float64], thr: float, angle_window: int,
                       range_window: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Twin of ``_kernels._local_maxima``."""
    size = (2 * angle_window + 1, 2 * range_window + 1)
    local = ndimage.maximum_filter(H, size=size, mode=("nearest", "wrap"))
    it, ir = np.nonzero((H >= local) & (H > thr))
    return it.astype(np.int64), ir.astype(np.int64)
