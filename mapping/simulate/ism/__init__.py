"""TODO docstring."""

from __future__ import annotations

from mapping.simulate.ism._config import (
    IsmConfig,
    range_limit_m,
    signal_period,
    spreading_power,
)
from mapping.simulate.ism._delay import (
    retarded_delay,
    retarded_delay_scalar,
)
from mapping.simulate.ism._engine import (
    iter_ism_blocks,
    reverb_period,
    simulate_stretch,
)
from mapping.simulate.ism._images import (
    candidate_images,
    mirror_maps,
)
from mapping.simulate.ism._paths import (
    PreparedScene,
    path_gains,
    prepare_scene,
    stretch_images,
    traced_gains,
)
from mapping.simulate.ism._render import (
    StretchPlan,
    delay_at_samples,
    gain_at_samples,
    path_table,
    plan_stretch,
    render_reference,
    render_stretch,
)
from mapping.simulate.ism._trace import (
    trace_images,
)

__all__ = [
    "IsmConfig",
    "PreparedScene",
    "StretchPlan",
    "candidate_images",
    "delay_at_samples",
    "gain_at_samples",
    "iter_ism_blocks",
    "mirror_maps",
    "path_gains",
    "path_table",
    "plan_stretch",
    "prepare_scene",
    "range_limit_m",
    "render_reference",
    "render_stretch",
    "retarded_delay",
    "retarded_delay_scalar",
    "reverb_period",
    "signal_period",
    "simulate_stretch",
    "spreading_power",
    "stretch_images",
    "trace_images",
    "traced_gains",
]
