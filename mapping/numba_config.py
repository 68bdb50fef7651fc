"""Compile flags shared by every numba kernel (one place, like stumpy's ``config.py``)."""

from __future__ import annotations

import os
from typing import Any

#: Flags for ``numba.njit`` in every ``_*_kernels.py`` module.
NUMBA_FLAGS: dict[str, Any] = dict(cache=True, fastmath=False, nogil=True)

#: Whether kernels may use ``prange`` (set OMNISONAR_NUMBA_PARALLEL=0 to disable).
PARALLEL: bool = os.environ.get("OMNISONAR_NUMBA_PARALLEL", "1") != "0"
