"""TODO docstring."""

from __future__ import annotations

from localization.particle_filter._config import (
    FilterConfig,
)
from localization.particle_filter._filter import (
    STATE_FORMAT,
    ParticleFilter,
    Steppable,
    block_odometry,
    init_global,
    init_tracked,
    inject,
    kld_count,
    predict,
    resample,
    run_filter,
    temper_to_ess,
    weigh,
)

__all__ = [
    "FilterConfig",
    "ParticleFilter",
    "STATE_FORMAT",
    "Steppable",
    "block_odometry",
    "init_global",
    "init_tracked",
    "inject",
    "kld_count",
    "predict",
    "resample",
    "run_filter",
    "temper_to_ess",
    "weigh",
]
