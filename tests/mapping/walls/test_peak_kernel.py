"""The heat-map peak kernel (``mapping.walls._kernels._local_maxima``) against its numpy twin
(the full ``scipy.ndimage.maximum_filter``): random maps, plateaus (ties), peaks at the
wrapped range edges and the clipped angle edges, and a real block's heat map."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.forward import WallSet, predicted_heatmap
from mapping.signal import SonarConfig
from mapping.walls import heatmap_peaks
from mapping.walls._kernels import _local_maxima  # private: tested directly
from tests.mapping.walls.naive import local_maxima_numpy


def _same(H: np.ndarray, thr: float, aw: int, rw: int) -> None:
    got = _local_maxima(np.ascontiguousarray(H), thr, aw, rw)
    want = local_maxima_numpy(H, thr, aw, rw)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


@settings(max_examples=60, deadline=None)
@given(rows=st.integers(1, 9), cols=st.integers(1, 60), aw=st.integers(0, 4),
       rw=st.integers(1, 30), levels=st.integers(2, 50), seed=st.integers(0, 2**31 - 1),
       thr_q=st.floats(0.0, 1.0))
def test_kernel_finds_the_filters_maxima(rows: int, cols: int, aw: int, rw: int, levels: int,
                                         seed: int, thr_q: float) -> None:
    """Coarse levels make plateaus (ties count as maxima, as ``H >= max_filter``); windows
    wider than the map wrap more than once in range and clip in angle."""
    H = np.random.default_rng(seed).integers(0, levels, size=(rows, cols)).astype(np.float64)
    _same(H, float(np.quantile(H, thr_q)), aw, rw)


def test_kernel_at_the_edges() -> None:
    H = np.zeros((5, 40))
    H[0, 0] = 3.0          # a corner: clipped rows, wrapped columns
    H[4, 39] = 2.0         # the opposite corner: 1 column (wrapped) but 4 rows away
    H[1, 38] = 2.5         # 2 columns (wrapped) and 1 row from the corner: not a maximum
    H[2, 20] = 1.0
    H[2, 21] = 1.0         # a plateau: both count
    _same(H, 0.5, 2, 3)
    rows, cols = _local_maxima(H, 0.5, 2, 3)
    assert list(zip(rows.tolist(), cols.tolist(), strict=True)) == [
        (0, 0), (2, 20), (2, 21), (4, 39)]   # (4, 39) is beaten only by (1, 38), 3 rows off


def test_a_blocks_peaks_are_unchanged() -> None:
    """On a real block (the forward model's heat map of a room) the kernel and the twin agree
    on the cropped map ``heatmap_peaks`` reads, at the default windows."""
    walls = WallSet.from_array(np.array([[0.0, 0.0, 5.0, 0.0], [5.0, 0.0, 5.0, 3.0],
                                         [5.0, 3.0, 0.0, 3.0], [0.0, 3.0, 0.0, 0.0]]))
    hm = predicted_heatmap(walls, np.array([1.2, 1.0, 0.4]), 0.15, SonarConfig())
    H = np.asarray(hm.H, dtype=np.float64)[:, :1500]
    thr = max(6.0 * float(np.median(H)), 0.08 * float(H.max()))
    _same(H, thr, 2, 12)
    assert heatmap_peaks(hm).range_m.size >= 4
