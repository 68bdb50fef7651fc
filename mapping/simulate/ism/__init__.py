"""The image-source engine: exact two-way Doppler of a moving monostatic sonar (the default).

Loudspeaker and microphone ride together, so every echo path is an image source that moves:
the robot mirrored through the walls in order, ``x -> A x + b``. For every path and sample the
retarded delay solves ``|x(t) - (A x(t - tau) + b)| = c tau``, so Doppler comes out of the
geometry rather than a formula. Paths are enumerated by beam tracing, traced on the finite
wall segments (occlusion, specular points) and faded in and out over 5 ms.

Entry points: `IsmConfig` (order, limits, spreading ``3d`` / ``2d``, fractional delay, noise,
reverberant tail, edge diffraction) and `iter_ism_blocks`, the engine registered as ``"ism"`` in
`mapping.simulate.ENGINES` (use `mapping.simulate.simulate_run`); `simulate_stretch` for a
stretch of samples; `path_table` for the ground truth of the rendered paths.

Notes
-----
Private modules: ``_config`` (`IsmConfig`, the signal a path is heard with), ``_images``
(candidate images, `mirror_maps`), ``_trace`` (validity on finite segments), ``_paths``
(which paths, with what gain), ``_delay`` (retarded delay by Newton), ``_render`` (delays and
gains carried to every sample), ``_kernels`` (the numba kernel summing the paths; its numpy
twin and the per-sample reference loop are in the tests), ``_engine`` (blocks, noise,
reverberation), ``_wedges`` (diffracting edges: free wall ends and outside corners, the UTD
coefficient), ``_diffraction`` (edge-diffracted paths: validity, gains, retarded delays).

Edge diffraction (``IsmConfig.diffraction_order``, off by default): free wall ends and outside
corners re-radiate (uniform theory of diffraction at rigid wedges), so an echo that ends at a
wall end no longer just fades out: the total stays continuous across the shadow boundary.
"""

from __future__ import annotations

from mapping.simulate.ism._config import (
    IsmConfig,
    diffraction_period,
    range_limit_m,
    signal_period,
    spreading_power,
)
from mapping.simulate.ism._delay import (
    retarded_delay,
    retarded_delay_scalar,
)
from mapping.simulate.ism._diffraction import (
    EdgePaths,
    edge_delay,
    edge_gains,
    edge_paths,
    edge_validity,
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
    path_table,
    plan_stretch,
    render_stretch,
)
from mapping.simulate.ism._trace import (
    trace_images,
)
from mapping.simulate.ism._wedges import (
    Wedges,
    diffracting_wedges,
    free_wall_ends,
    transition,
    utd_sum,
    wedge_angle,
)

__all__ = [
    "EdgePaths",
    "IsmConfig",
    "PreparedScene",
    "StretchPlan",
    "Wedges",
    "candidate_images",
    "diffracting_wedges",
    "diffraction_period",
    "edge_delay",
    "edge_gains",
    "edge_paths",
    "edge_validity",
    "free_wall_ends",
    "iter_ism_blocks",
    "mirror_maps",
    "path_gains",
    "path_table",
    "plan_stretch",
    "prepare_scene",
    "range_limit_m",
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
    "transition",
    "utd_sum",
    "wedge_angle",
]
