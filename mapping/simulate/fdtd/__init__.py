"""The FDTD reference simulator of a moving sonar (paper Sec. 3, eqs. 6-17, Table 2).

A 2-D staggered-grid p-q FDTD (eqs. 9-11) with a graded split-field PML, walls on velocity
nodes (rigid, or locally reacting for a finite impedance), and the moving source and receiver
placed by the direct method with bilinear weights (eqs. 12-17). Two fields advance in the same
sweep, with and without walls; their difference at the receiver is the received signal without
the direct wave. Slow and exact where the image-source engine is not (diffraction at free wall
ends); its grid dispersion is predicted (`numerical_wavenumber`, `numerical_group_velocity`).

Entry points: `FdtdConfig` (frozen; Table 2 defaults) and `simulate_fdtd` (scene + path ->
`mapping.run.Run`); for progress, checkpoints and resuming, `setup_for_scene` / `setup_fdtd`
(`FdtdSetup` with its `FdtdReport`), `new_state`, `iter_fdtd` (a generator of `FdtdProgress`),
`restore_state` and `setup_fingerprint`; `iter_fdtd_blocks` is the engine registered as
``"fdtd"`` in `mapping.simulate.ENGINES`. `FdtdSolver` steps the fields of one grid
(``backend="numba"``: temporal blocking, `STEPS_PER_SWEEP` steps per sweep;
``"numba-step"``: one step per sweep, the baseline; ``"numpy"``: the twin);
`leapfrog_energy` is the discrete energy the scheme conserves.

Notes
-----
Private modules: ``_config`` (`FdtdConfig`, Courant and band checks), ``_grid`` (fitting the
grid, rasterizing walls, PML coefficients, stencils), ``_dispersion`` (dispersion, the
injected source signal, resampling to the sonar rate), ``_solver`` (`FdtdSolver`, the only
user of the kernels), ``_kernels`` (numba kernels of eqs. 9-11), ``_engine`` (set-up, state,
stepping a run).
"""

from __future__ import annotations

from mapping.simulate.fdtd._config import (
    FdtdConfig,
    check_courant,
    courant_number,
    injected_band,
)
from mapping.simulate.fdtd._dispersion import (
    FdtdReport,
    numerical_group_velocity,
    numerical_wavenumber,
    resample_to_rate,
    source_filter,
    source_signal,
)
from mapping.simulate.fdtd._engine import (
    FdtdProgress,
    FdtdSetup,
    FdtdState,
    advance,
    block_samples,
    default_chunk_steps,
    finished_blocks,
    iter_fdtd,
    iter_fdtd_blocks,
    new_state,
    path_position,
    restore_state,
    run_meta,
    setup_fdtd,
    setup_fingerprint,
    setup_for_scene,
    sim_block,
    simulate_fdtd,
    steps_needed,
)
from mapping.simulate.fdtd._grid import (
    FdtdCoefficients,
    FdtdGrid,
    WallNodes,
    bilinear_stencil,
    fit_grid,
    make_coefficients,
    rasterize_walls,
    scene_walls,
    wall_nodes,
)
from mapping.simulate.fdtd._solver import (
    STEPS_PER_SWEEP,
    FdtdSolver,
    leapfrog_energy,
    sweep_plan,
)

__all__ = [
    "FdtdCoefficients",
    "FdtdConfig",
    "FdtdGrid",
    "FdtdProgress",
    "FdtdReport",
    "FdtdSetup",
    "FdtdSolver",
    "FdtdState",
    "STEPS_PER_SWEEP",
    "WallNodes",
    "advance",
    "bilinear_stencil",
    "block_samples",
    "check_courant",
    "courant_number",
    "default_chunk_steps",
    "finished_blocks",
    "fit_grid",
    "injected_band",
    "iter_fdtd",
    "iter_fdtd_blocks",
    "leapfrog_energy",
    "make_coefficients",
    "new_state",
    "numerical_group_velocity",
    "numerical_wavenumber",
    "path_position",
    "rasterize_walls",
    "resample_to_rate",
    "restore_state",
    "run_meta",
    "scene_walls",
    "setup_fdtd",
    "setup_fingerprint",
    "setup_for_scene",
    "sim_block",
    "simulate_fdtd",
    "source_filter",
    "source_signal",
    "steps_needed",
    "sweep_plan",
    "wall_nodes",
]
