"""FDTD reference simulator of a moving sonar (paper Sec. 3, eqs. 6-17, Table 2).

A 2-D staggered-grid p-q FDTD (eqs. 9-11) with a graded perfectly matched layer on the
outer border, walls as rigid (or finite-impedance) velocity nodes, and the moving source and
receiver placed on the grid by the direct method with bilinear weights (eqs. 12-17). Two
fields advance in the same sweep: one with the walls and one without; their difference at
the receiver is the received signal without the direct wave, as in the paper.

Conventions
-----------
- Cell ``(i, j)`` has its pressure node at ``origin_m + (i, j) * grid_step_m``; ``qx[i, j]``
  sits half a cell before it in x, ``qy[i, j]`` half a cell before it in y. Cell centres are
  placed at odd multiples of ``grid_step_m / 2`` so that walls on round coordinates fall on
  velocity nodes, never on pressure nodes.
- Bilinear weights (eqs. 12-17). The paper writes ``zeta = 2 (x - floor(x / dx)) / dx - 1``,
  mixing metres and cell indices; the intended coordinate, used here, is
  ``u = (x - x0) / dx``, ``zeta = 2 (u - floor(u)) - 1`` (and ``eta`` likewise), with the four
  nodes ``floor(u)`` and ``floor(u) + 1`` (not ``ceil``, which collapses onto ``floor`` on a
  node). The weights ``(1 -+ zeta)(1 -+ eta) / 4`` are non-negative and sum to 1.
- Source: a mass (volume-velocity) source ``dp/dt += rho c^2 Q(t) delta(x - x_s)``. ``Q`` is
  the transmitted signal (``mapping.signal``) filtered so that the free-field pressure far
  from a static source is ``s(t - r / c) / sqrt(r)`` (r in metres): the 2-D Green's function
  has a half-derivative and a -pi/4 phase, which the filter undoes. The filter also
  band-limits the signal to what the grid carries (raised-cosine taper to ``max_frequency``).
- Denormals: the pressure is stored with a constant offset (``1e-6`` of the source scale);
  differences of stored pressures are then either zero or far above the subnormal range, and
  the decaying fields inside the PML are flushed to zero below ``1e-30``. The benchmark
  measures the effect.

Modules: :mod:`mapping.simulate.fdtd_config` (FdtdConfig, Courant limit, injected band);
:mod:`mapping.simulate.fdtd_grid` (grid fitting, scene walls and their rasterization, bilinear
stencil, PML coefficients); :mod:`mapping.simulate.fdtd_dispersion` (numerical dispersion, set-up
report, source signal, resampling); :mod:`mapping.simulate.fdtd_solver` (time stepping over the
numba kernels). This module runs the moving sonar (set-up, state, chunks, blocks) and
re-exports the public names of the others.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mapping.run import Run
from mapping.signal import SonarConfig
from mapping.simulate._base import (
    PathTable,
    SceneLike,
    SimBlock,
    TrajectoryLike,
    assemble_run,
    block_mean_odometry,
)
from mapping.simulate.fdtd._config import FdtdConfig, check_courant
from mapping.simulate.fdtd._dispersion import (
    _RESAMPLE_HALF_WIDTH,
    FdtdReport,
    _report,
    resample_to_rate,
    source_signal,
)
from mapping.simulate.fdtd._grid import (
    FdtdGrid,
    WallNodes,
    bilinear_stencil,
    fit_grid,
    scene_walls,
    wall_nodes,
)
from mapping.simulate.fdtd._solver import FdtdSolver

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]



# ---- the moving-sonar simulation ----------------------------------------------------------
def path_position(trajectory: TrajectoryLike, t_s: ArrayLike) -> FloatArray:
    """Position (n, 2) at ``t_s``; before 0 and after the end the motion continues straight
    at the end velocity (steady state of the endless transmission)."""
    t = np.asarray(t_s, dtype=np.float64)
    end = float(trajectory.duration_s)
    tc = np.clip(t, 0.0, end)
    pos = np.asarray(trajectory.position(tc), dtype=np.float64).reshape(-1, 2)
    before, after = t < 0, t > end
    if before.any():
        v0 = np.asarray(trajectory.velocity(np.array([0.0])), np.float64).reshape(2)
        pos[before] += (t[before] - 0.0)[:, None] * v0
    if after.any():
        v1 = np.asarray(trajectory.velocity(np.array([end])), np.float64).reshape(2)
        pos[after] += (t[after] - end)[:, None] * v1
    return pos


@dataclass(frozen=True)
class FdtdSetup:
    """Everything fixed before the first step of a moving-sonar run."""

    sonar: SonarConfig
    fdtd: FdtdConfig
    grid: FdtdGrid
    walls: WallNodes
    c: float
    n_blocks: int
    t_start_s: float
    n_steps: int
    report: FdtdReport
    segments_m: FloatArray
    impedance_pa_s_m: FloatArray
    trajectory: TrajectoryLike
    first_block: int = 0


@dataclass
class FdtdState:
    """Mutable progress of a run: the solver fields, steps done and the received series
    (one value per step: field with walls minus field without, at the receiver)."""

    solver: FdtdSolver
    step: int = 0
    received: FloatArray = field(default_factory=lambda: np.zeros(0))

    def to_arrays(self) -> dict[str, NDArray[Any]]:
        """Arrays of a checkpoint."""
        arrays = self.solver.state_arrays()
        arrays["step"] = np.array(self.step)
        arrays["received"] = self.received[: self.step].copy()
        return arrays


@dataclass(frozen=True)
class FdtdProgress:
    """Yielded after each chunk of steps."""

    steps_done: int
    steps_total: int
    state: FdtdState


def setup_fdtd(segments_m: FloatArray, impedance_pa_s_m: FloatArray,
               trajectory: TrajectoryLike, sonar: SonarConfig, fdtd: FdtdConfig,
               n_blocks: int | None = None, first_block: int = 0) -> FdtdSetup:
    """Fit the grid, rasterize the walls and plan the steps of a moving-sonar run.

    Parameters
    ----------
    segments_m : ndarray, shape (W, 2, 2)
        Wall segments [[x0, y0], [x1, y1]] in metres.
    impedance_pa_s_m : ndarray, shape (W,)
        Normal acoustic impedance of each wall (inf = rigid, Table 2).
    trajectory : TrajectoryLike
        Sonar path (source and receiver co-located).
    sonar, fdtd : SonarConfig, FdtdConfig
    n_blocks : int or None
        Blocks to simulate; None: as many whole blocks as the path lasts (at least 1).
    first_block : int
        Index of the first block (block k starts at ``k * block_s``); the warm-up precedes it.

    Raises
    ------
    ValueError
        Courant number above 1 / sqrt(2), bad shapes, n_blocks < 1.

    Warns
    -----
    UserWarning
        Fewer than ``fdtd.warn_points_per_wavelength`` grid points per wavelength at the
        injected band edge.
    """
    c = fdtd.speed(sonar)
    courant = check_courant(fdtd, c)
    seg = np.asarray(segments_m, dtype=np.float64).reshape(-1, 2, 2)
    z = np.broadcast_to(np.asarray(impedance_pa_s_m, dtype=np.float64), (seg.shape[0],)).copy()
    if n_blocks is None:
        n_blocks = max(1, int(math.floor(float(trajectory.duration_s) / sonar.block_s + 1e-9)))
    if n_blocks < 1:
        raise ValueError(f"n_blocks must be >= 1, got {n_blocks}")
    if first_block < 0:
        raise ValueError(f"first_block must be >= 0, got {first_block}")
    t0 = first_block * sonar.block_s
    t_end = (first_block + n_blocks) * sonar.block_s
    path = path_position(trajectory, np.linspace(t0, t_end, 512))
    points = np.concatenate([seg.reshape(-1, 2), path]) if seg.size else path
    grid = fit_grid(points, fdtd)
    nx, ny = grid.shape
    diag = math.hypot(nx, ny) * fdtd.grid_step_m
    warmup = 2 * diag / c if fdtd.warmup_s is None else fdtd.warmup_s
    dt = fdtd.time_step_s
    warmup_steps = int(math.ceil(warmup / dt))
    t_start = t0 - warmup_steps * dt
    n_steps = warmup_steps + int(math.ceil((t_end - t0) / dt)) + _RESAMPLE_HALF_WIDTH + 2
    pre = path_position(trajectory, np.array([t_start]))
    grid_all = fit_grid(np.concatenate([points, pre]), fdtd)
    walls = wall_nodes(seg, z, grid_all, fdtd, c)
    report = _report(grid_all, sonar, fdtd, c, courant, n_steps, warmup_steps)
    if report.points_per_wavelength_injected_edge < fdtd.warn_points_per_wavelength:
        warnings.warn(
            f"FDTD grid: {report.points_per_wavelength_injected_edge:.1f} points per wavelength "
            f"at the injected band edge {report.injected_max_hz / 1e3:.3g} kHz (< "
            f"{fdtd.warn_points_per_wavelength:g}); group-velocity error there "
            f"{report.group_velocity_error_injected_edge[0] * 100:+.1f} % (axis)",
            stacklevel=2,
        )
    return FdtdSetup(sonar, fdtd, grid_all, walls, c, n_blocks, t_start, n_steps, report,
                     seg, z, trajectory, first_block)


def new_state(setup: FdtdSetup, backend: str = "numba") -> FdtdState:
    """Zero fields (quiet before the warm-up starts)."""
    solver = FdtdSolver(setup.grid, setup.fdtd, setup.c, setup.walls, 2, backend)
    return FdtdState(solver=solver, step=0, received=np.zeros(setup.n_steps))


def restore_state(setup: FdtdSetup, arrays: dict[str, NDArray[Any]],
                  backend: str = "numba") -> FdtdState:
    """State from checkpoint arrays (see :meth:`FdtdState.to_arrays`)."""
    state = new_state(setup, backend)
    state.solver.load_state(arrays)
    step = int(arrays["step"])
    if not 0 <= step <= setup.n_steps:
        raise ValueError(f"checkpoint step {step} outside 0..{setup.n_steps}")
    state.step = step
    state.received[:step] = np.asarray(arrays["received"])[:step]
    return state


def advance(setup: FdtdSetup, state: FdtdState, n: int) -> None:
    """Advance ``state`` by up to ``n`` steps of the run (moving source and receiver)."""
    n = min(n, setup.n_steps - state.step)
    if n <= 0:
        return
    dt = setup.fdtd.time_step_s
    steps = state.step + np.arange(n)
    t_mid = setup.t_start_s + (steps + 0.5) * dt
    t_rx = setup.t_start_s + (steps + 1.0) * dt
    si, sj, sw = bilinear_stencil(path_position(setup.trajectory, t_mid), setup.grid)
    ri, rj, rw = bilinear_stencil(path_position(setup.trajectory, t_rx), setup.grid)
    g = source_signal(t_mid, setup.sonar, setup.fdtd)
    out = state.solver.run(si, sj, sw, g, ri, rj, rw)
    state.received[state.step: state.step + n] = out[:, 0] - out[:, 1]
    state.step += n


def block_samples(setup: FdtdSetup, state: FdtdState, k: int) -> FloatArray:
    """Received samples of block ``k`` (absolute index) at the sonar rate; needs
    :func:`steps_needed` steps done."""
    B = setup.sonar.block_samples
    t_first = setup.t_start_s + setup.fdtd.time_step_s  # received[m] is at t_start + (m+1) dt
    return resample_to_rate(state.received[: state.step], t_first, setup.fdtd.time_step_s,
                            setup.sonar.fs_hz, k * B, B)


def steps_needed(setup: FdtdSetup, k: int) -> int:
    """Steps after which block ``k`` can be resampled."""
    t_last = ((k + 1) * setup.sonar.block_samples - 1) / setup.sonar.fs_hz
    m = int(math.floor((t_last - setup.t_start_s) / setup.fdtd.time_step_s))
    return min(setup.n_steps, m + _RESAMPLE_HALF_WIDTH + 1)


def iter_fdtd(setup: FdtdSetup, state: FdtdState | None = None,
              chunk_steps: int = 2000) -> Iterator[FdtdProgress]:
    """Run the remaining steps of ``setup`` in chunks, yielding progress after each.

    The caller may stop at any yield and checkpoint ``progress.state.to_arrays()``; a later
    call with the restored state continues exactly where it stopped.
    """
    if chunk_steps < 1:
        raise ValueError(f"chunk_steps must be >= 1, got {chunk_steps}")
    state = new_state(setup) if state is None else state
    while state.step < setup.n_steps:
        advance(setup, state, chunk_steps)
        yield FdtdProgress(state.step, setup.n_steps, state)


def _empty_paths() -> PathTable:
    e = np.zeros(0)
    return PathTable(order=np.zeros(0, np.int64), walls=(), delay_s=e, doppler_factor=e,
                     angle_to_velocity_rad=e, reflection=e, amplitude=e)


def sim_block(setup: FdtdSetup, state: FdtdState, k: int) -> SimBlock:
    """Block ``k`` (absolute index) as a :class:`~mapping.simulate.base.SimBlock`; the
    path table is empty (the FDTD does not separate echo paths)."""
    if state.step < steps_needed(setup, k):
        raise ValueError(f"block {k} needs {steps_needed(setup, k)} steps, {state.step} done")
    traj = setup.trajectory
    t_mid = np.array([(k + 0.5) * setup.sonar.block_s])
    speed, yaw_rate = block_mean_odometry(traj, k * setup.sonar.block_s,
                                          (k + 1) * setup.sonar.block_s)
    return SimBlock(
        index=k, samples=block_samples(setup, state, k), t_s=k * setup.sonar.block_s,
        pose=np.asarray(traj.pose(t_mid), dtype=np.float64).reshape(3),
        speed_m_s=speed, yaw_rate_rad_s=yaw_rate,
        paths=_empty_paths(), meta={"engine": "fdtd"},
    )


def finished_blocks(setup: FdtdSetup, state: FdtdState) -> list[SimBlock]:
    """The blocks of a completed run (``state.step == setup.n_steps``)."""
    if state.step < setup.n_steps:
        raise ValueError(f"run incomplete: {state.step} of {setup.n_steps} steps done")
    ks = range(setup.first_block, setup.first_block + setup.n_blocks)
    return [sim_block(setup, state, k) for k in ks]


def iter_fdtd_blocks(scene: SceneLike, trajectory: TrajectoryLike, config: SonarConfig,
                     n_blocks: int, engine: FdtdConfig, rng: np.random.Generator | None = None,
                     first_block: int = 0, chunk_steps: int = 2000) -> Iterator[SimBlock]:
    """The FDTD engine behind :func:`mapping.simulate.iter_blocks`: blocks in order, each
    yielded as soon as the steps covering it are done (``rng`` unused: deterministic)."""
    setup = setup_for_scene(scene, trajectory, config, engine, n_blocks, first_block)
    state = new_state(setup)
    k = first_block
    for progress in iter_fdtd(setup, state, chunk_steps):
        while k < first_block + n_blocks and progress.steps_done >= steps_needed(setup, k):
            yield sim_block(setup, state, k)
            k += 1


def setup_for_scene(scene: SceneLike, trajectory: TrajectoryLike, sonar: SonarConfig,
                    fdtd: FdtdConfig, n_blocks: int | None = None,
                    first_block: int = 0) -> FdtdSetup:
    """:func:`setup_fdtd` for a :class:`~mapping.scene.Scene`-like object."""
    seg, z = scene_walls(scene, fdtd.density_kg_m3, fdtd.speed(sonar))
    return setup_fdtd(seg, z, trajectory, sonar, fdtd, n_blocks, first_block)


def run_meta(setup: FdtdSetup) -> dict[str, Any]:
    """Run-file ``meta`` of an FDTD run (engine, config, set-up report)."""
    return {"engine": "fdtd", "engine_config": setup.fdtd.to_dict(),
            "fdtd_report": asdict(setup.report), "direct_path": False,
            "path": getattr(setup.trajectory, "name", None)}


def simulate_fdtd(scene: SceneLike, trajectory: TrajectoryLike, sonar: SonarConfig,
                  fdtd: FdtdConfig | None = None, n_blocks: int | None = None) -> Run:
    """Simulate a whole run with the FDTD engine (no progress, no checkpoints).

    Returns the same :class:`~mapping.runfile.Run` as the image-source engine.
    """
    setup = setup_for_scene(scene, trajectory, sonar, fdtd or FdtdConfig(), n_blocks)
    state = new_state(setup)
    for _ in iter_fdtd(setup, state):
        pass
    return assemble_run(finished_blocks(setup, state), sonar, scene.to_json(), run_meta(setup))


def setup_fingerprint(setup: FdtdSetup) -> str:
    """Hash of everything that fixes the step sequence (a checkpoint resumes only onto an
    identical set-up)."""
    import hashlib
    import json

    key = {
        "sonar": setup.sonar.to_json(), "fdtd": setup.fdtd.to_dict(), "shape": setup.grid.shape,
        "origin": setup.grid.origin_m, "n_steps": setup.n_steps, "t_start": setup.t_start_s,
        "segments": setup.segments_m.round(9).tolist(),
        "impedance": [str(z) for z in setup.impedance_pa_s_m],
        "path": path_position(setup.trajectory, np.linspace(setup.t_start_s, setup.t_start_s
                                                            + setup.n_steps
                                                            * setup.fdtd.time_step_s,
                                                            64)).round(9).tolist(),
        "first_block": setup.first_block,
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def default_chunk_steps(setup: FdtdSetup) -> int:
    """Steps per progress report: about 3e8 cell updates (a second or two)."""
    nx, ny = setup.grid.shape
    return int(max(20, min(5000, 3e8 // (nx * ny))))
