"""Offline posterior analysis of the pose (x, y, heading) with emcee (issue 8).

The posterior of one block or of a window of blocks tied by odometry,
``log p(theta | H_0..H_{K-1}) = log prior(theta) + sum_k log L(H_k | theta (+) u_k, G)``,
with ``theta`` the pose at the first block's midpoint, ``u_k`` the exact arc composition of the
odometry and ``L`` the sensor model of `localization.sensor` (unfloored). It is sampled in
steps: the log posterior on a coarse grid over the prior, modes by persistence clustering,
one emcee ensemble per mode (DEMove 0.8 + a corrected `SnookerMove` 0.2) run until the kept
chain is long enough in autocorrelation times, and per mode a fine reference grid for mass,
Hellinger distance, KL and HPD coverage.

Entry points: `sample_posterior` (-> `PosteriorResult`) and `iter_posterior` (the same as a
generator of `Progress` events) with `PosteriorSettings`; `window_from_run` /
`sensor_window_log_likelihood` / `prior_from_tables` to build the likelihood and the
`PosePrior`; `result_arrays` (the record written by ``omnisonar posterior``);
`compare_cloud` (a particle filter's cloud against the posterior).

Notes
-----
Private modules: ``_window`` (poses, odometry windows, window likelihood, prior), ``_grid``
(grid posterior and its modes), ``_moves`` (walkers, moves, convergence), ``_sampler`` (the
sampling steps), ``_diagnostics`` (summaries, HPD, comparison with grids and clouds),
``_records`` (settings and result records).
"""

from __future__ import annotations

from localization.posterior._diagnostics import (
    CloudCalibration,
    compare_cloud,
    compare_with_grid,
    hpd_thresholds,
    summarize_samples,
)
from localization.posterior._grid import (
    GridModes,
    GridPosterior,
    find_grid_modes,
    full_turn_headings,
    grid_log_posterior,
    local_grid,
    mode_heading_center,
)
from localization.posterior._moves import (
    SnookerMove,
    autocorr_check,
    make_moves,
    run_ensemble,
    walkers_from_cloud,
    walkers_from_grid,
)
from localization.posterior._records import (
    ChainRun,
    GridComparison,
    ModeSummary,
    PosteriorResult,
    PosteriorSettings,
    Progress,
    result_arrays,
)
from localization.posterior._sampler import (
    iter_posterior,
    log_posterior,
    merge_overlapping,
    sample_posterior,
)
from localization.posterior._window import (
    NDIM,
    TWO_PI,
    LogLikelihood,
    PosePrior,
    arc_offset,
    check_block_range,
    compose,
    invert,
    prior_from_tables,
    sensor_window_log_likelihood,
    window_from_run,
    window_log_likelihood,
    window_offsets,
)

__all__ = [
    "ChainRun",
    "CloudCalibration",
    "GridComparison",
    "GridModes",
    "GridPosterior",
    "LogLikelihood",
    "ModeSummary",
    "NDIM",
    "PosePrior",
    "PosteriorResult",
    "PosteriorSettings",
    "Progress",
    "SnookerMove",
    "TWO_PI",
    "arc_offset",
    "autocorr_check",
    "check_block_range",
    "compare_cloud",
    "compare_with_grid",
    "compose",
    "find_grid_modes",
    "full_turn_headings",
    "grid_log_posterior",
    "hpd_thresholds",
    "invert",
    "iter_posterior",
    "local_grid",
    "log_posterior",
    "make_moves",
    "merge_overlapping",
    "mode_heading_center",
    "prior_from_tables",
    "result_arrays",
    "run_ensemble",
    "sample_posterior",
    "sensor_window_log_likelihood",
    "summarize_samples",
    "walkers_from_cloud",
    "walkers_from_grid",
    "window_from_run",
    "window_log_likelihood",
    "window_offsets",
]
