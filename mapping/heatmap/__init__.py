"""The Doppler direction-of-arrival heat map (paper Sec. 2.1, eq. 1).

One received block (M periods of the m-sequence) and the odometry speed give a polar heat map
``H[n_theta, n_tau]``: for every direction ``theta_n = pi n / N`` of the bank the block is
resampled by the Doppler ratio ``alpha_n = (c - v cos theta_n) / (c + v cos theta_n)`` about
its centre, its periods are folded and circularly correlated with one transmitted period, and
the envelope is taken. Angles count from the direction of travel (0..pi: left and right are
the same row), ranges are ``c n_tau / (2 fs)``.

Entry points: `doppler_heatmap` (one block -> `HeatMap`), `heatmap_of_run` (block ``k`` of a
`mapping.run.Run`, with the neighbouring samples the stretched window needs), `find_peak`
(the strongest echo, refined by parabolas); the bank itself: `bank_angles`,
`doppler_ratios`, `required_margin`, `resample_about_centre`, `bank_envelope`.

Notes
-----
Private modules: ``_heatmap`` validates the input, builds the `HeatMap` and reads its peak;
``_resampling`` holds the Doppler resampling of eq. 1 in its two implementations,
``method="spectral"`` (default: a DFT of the unresampled block at the scaled frequencies,
Kaiser-Bessel gridding) and ``method="direct"`` (a Kaiser-windowed sinc in time);
``_kernels`` holds their numba kernels, whose numpy twins live in the tests
(``tests/mapping/heatmap/naive.py``).
"""

from __future__ import annotations

from mapping.heatmap._heatmap import (
    MIN_DRIFT_SAMPLES,
    HeatMap,
    Peak,
    doppler_heatmap,
    find_peak,
    heatmap_of_run,
)
from mapping.heatmap._resampling import (
    CUTOFF,
    DEFAULT_TAPS,
    KAISER_BETA,
    PHASES,
    SPECTRAL_TAPS,
    STRIP_STEP_RAD,
    Bank,
    Method,
    bank_angles,
    bank_envelope,
    doppler_ratios,
    polyphase_table,
    required_margin,
    resample_about_centre,
)

__all__ = [
    "Bank",
    "CUTOFF",
    "DEFAULT_TAPS",
    "HeatMap",
    "KAISER_BETA",
    "MIN_DRIFT_SAMPLES",
    "Method",
    "PHASES",
    "Peak",
    "SPECTRAL_TAPS",
    "STRIP_STEP_RAD",
    "bank_angles",
    "bank_envelope",
    "doppler_heatmap",
    "doppler_ratios",
    "find_peak",
    "heatmap_of_run",
    "polyphase_table",
    "required_margin",
    "resample_about_centre",
]
