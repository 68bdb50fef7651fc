"""Settings and result records of the pose posterior (:mod:`localization.posterior`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from localization.posterior._grid import GridModes, GridPosterior
from localization.posterior._window import NDIM, FloatArray


# ---- settings, results ----------------------------------------------------------------
@dataclass(frozen=True)
class PosteriorSettings:
    """Parameters of :func:`iter_posterior`.

    Attributes
    ----------
    n_walkers : int
        Walkers per ensemble (one ensemble per mode), >= 2 * 3.
    n_steps : int
        First batch of steps per ensemble, >= 1.
    max_steps : int
        Cap on steps per ensemble while extending towards ``tau_multiple`` autocorrelation times.
    tau_multiple : float
        Required kept chain length in integrated autocorrelation times (emcee advice: 50).
    de_weight : float
        Share of DEMove in the move mixture; the rest is a snooker move (emcee docs: 0.8/0.2).
    snooker : {"corrected", "emcee"}
        Which snooker move: :class:`SnookerMove` (default) or emcee's biased DESnookerMove.
    grid_step_m, grid_heading_step_rad : float
        Coarse global grid for mode finding and masses.
    persistence_nats, min_mode_mass, mass_level : float
        Mode finding, see :func:`find_grid_modes`.
    local_grid_cells : int
        Cells per axis of each mode's fine reference grid.
    local_grid_sigmas : float
        Half-width of that grid in posterior standard deviations.
    compare_bins : int
        Bins per axis of the shared histogram comparing samples with the grid posterior.
    """

    n_walkers: int = 32
    n_steps: int = 1000
    max_steps: int = 20_000
    tau_multiple: float = 50.0
    de_weight: float = 0.8
    snooker: str = "corrected"
    grid_step_m: float = 0.05
    grid_heading_step_rad: float = math.radians(10.0)
    persistence_nats: float = 3.0
    min_mode_mass: float = 0.01
    mass_level: float = 0.999
    local_grid_cells: int = 25
    local_grid_sigmas: float = 4.5
    compare_bins: int = 8

    def __post_init__(self) -> None:
        if self.n_walkers < 2 * NDIM:
            raise ValueError(f"n_walkers must be >= 2 * dim = {2 * NDIM}, got {self.n_walkers}")
        if self.n_steps < 1:
            raise ValueError(f"n_steps must be >= 1, got {self.n_steps}")
        if self.max_steps < self.n_steps:
            raise ValueError(f"max_steps must be >= n_steps = {self.n_steps}, "
                             f"got {self.max_steps}")
        if not self.tau_multiple > 0:
            raise ValueError(f"tau_multiple must be > 0, got {self.tau_multiple}")
        if not 0 <= self.de_weight <= 1:
            raise ValueError(f"de_weight must be in [0, 1], got {self.de_weight}")
        if self.snooker not in ("corrected", "emcee"):
            raise ValueError(f"snooker must be 'corrected' or 'emcee', got {self.snooker!r}")
        if not self.grid_step_m > 0:
            raise ValueError(f"grid_step_m must be > 0, got {self.grid_step_m}")
        if not 0 < self.grid_heading_step_rad <= math.pi:
            raise ValueError(f"grid_heading_step_rad must be in (0, pi], "
                             f"got {self.grid_heading_step_rad}")
        if self.local_grid_cells < 3:
            raise ValueError(f"local_grid_cells must be >= 3, got {self.local_grid_cells}")
        if not self.local_grid_sigmas > 0:
            raise ValueError(f"local_grid_sigmas must be > 0, got {self.local_grid_sigmas}")
        if self.compare_bins < 2:
            raise ValueError(f"compare_bins must be >= 2, got {self.compare_bins}")


@dataclass(frozen=True)
class GridComparison:
    """Sampler against the grid posterior on a shared histogram (one mode's box).

    ``hellinger`` in [0, 1]; ``hellinger_iid`` is the same distance for ``n_effective`` exact
    draws from the grid (what sampling noise alone gives); ``kl_grid_to_samples`` is
    KL(grid || samples) in nats with half-count smoothing; ``coverage68/95`` is the grid's
    mass inside the sampler's 68 / 95 % highest-density bins (ideal: about 0.68 / 0.95);
    ``outside`` the share of samples outside the box.
    """

    hellinger: float
    hellinger_iid: float
    kl_grid_to_samples: float
    coverage68: float
    coverage95: float
    outside: float
    n_effective: float


@dataclass(frozen=True)
class ModeSummary:
    """One mode: its mass, moments, intervals and chain diagnostics.

    ``mean`` is (x_m, y_m, circular mean heading_rad); ``cov`` the covariance with heading
    unwrapped about that mean; ``interval68/95`` (3, 2) equal-tailed intervals per axis
    (heading unwrapped, may leave (-pi, pi]); ``tau`` the integrated autocorrelation times of
    x, y, cos(heading), sin(heading) in steps; ``converged`` whether the kept chain is
    >= ``tau_multiple`` times the largest tau.
    """

    mass: float
    mass_coarse: float
    mean: FloatArray
    cov: FloatArray
    heading_resultant_length: float
    heading_circular_std_rad: float
    interval68: FloatArray
    interval95: FloatArray
    tau: FloatArray
    acceptance_fraction: float
    n_steps: int
    discard: int
    thin: int
    converged: bool
    comparison: GridComparison
    local_grid: GridPosterior = field(repr=False)


@dataclass(frozen=True)
class PosteriorResult:
    """Samples and diagnostics of the pose posterior.

    ``samples`` (n, 3) with heading wrapped to (-pi, pi]; ``weights`` (n,) sum to 1 and carry
    each mode's mass; ``mode_index`` (n,) the ensemble each sample came from;
    ``hpd_log_prob[i]`` the log-posterior threshold of the ``hpd_levels[i]`` highest-density
    region and ``hpd_volume[i]`` its volume in m^2 rad (from the modes' fine grids).
    """

    samples: FloatArray
    log_prob: FloatArray
    weights: FloatArray
    mode_index: NDArray[np.int64]
    modes: tuple[ModeSummary, ...]
    hpd_levels: tuple[float, ...]
    hpd_log_prob: tuple[float, ...]
    hpd_volume: tuple[float, ...]
    grid: GridPosterior = field(repr=False)
    grid_modes: GridModes = field(repr=False)
    settings: PosteriorSettings

    @property
    def converged(self) -> bool:
        """True when every ensemble reached ``tau_multiple`` autocorrelation times."""
        return all(m.converged for m in self.modes)


@dataclass(frozen=True)
class Progress:
    """One event of :func:`iter_posterior`: stage "grid", "sample" (per step) or "done"."""

    stage: str
    mode: int = 0
    n_modes: int = 0
    step: int = 0
    planned_steps: int = 0
    result: PosteriorResult | None = None


@dataclass(frozen=True)
class ChainRun:
    """One ensemble's chain (steps, walkers, 3) and its convergence bookkeeping."""

    chain: FloatArray
    log_prob: FloatArray
    tau: FloatArray
    discard: int
    thin: int
    acceptance_fraction: float
    converged: bool


def result_arrays(result: PosteriorResult) -> dict[str, FloatArray]:
    """The result as flat arrays for an ``.npz`` record (see the README's posterior format)."""
    modes = result.modes
    return {
        "samples": result.samples,
        "log_prob": result.log_prob,
        "weights": result.weights,
        "mode_index": result.mode_index.astype(np.float64),
        "mode_mass": np.array([m.mass for m in modes]),
        "mode_mass_coarse": np.array([m.mass_coarse for m in modes]),
        "mode_mean": np.array([m.mean for m in modes]),
        "mode_cov": np.array([m.cov for m in modes]),
        "mode_interval68": np.array([m.interval68 for m in modes]),
        "mode_interval95": np.array([m.interval95 for m in modes]),
        "mode_heading_circular_std_rad": np.array([m.heading_circular_std_rad for m in modes]),
        "mode_tau": np.array([m.tau for m in modes]),
        "mode_acceptance": np.array([m.acceptance_fraction for m in modes]),
        "mode_n_steps": np.array([m.n_steps for m in modes], dtype=np.float64),
        "mode_converged": np.array([m.converged for m in modes], dtype=np.float64),
        "mode_hellinger": np.array([m.comparison.hellinger for m in modes]),
        "mode_hellinger_iid": np.array([m.comparison.hellinger_iid for m in modes]),
        "mode_kl": np.array([m.comparison.kl_grid_to_samples for m in modes]),
        "mode_coverage68": np.array([m.comparison.coverage68 for m in modes]),
        "mode_coverage95": np.array([m.comparison.coverage95 for m in modes]),
        "hpd_levels": np.array(result.hpd_levels),
        "hpd_log_prob": np.array(result.hpd_log_prob),
        "hpd_volume_m2_rad": np.array(result.hpd_volume),
    }
