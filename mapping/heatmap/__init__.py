"""TODO docstring."""

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
    Engine,
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
    "Engine",
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
