"""Configuration of the FDTD engine (paper Sec. 3, Table 2) and its stability and band checks.

:class:`FdtdConfig` holds the grid, time step, PML and numeric options; the Courant number
``c dt / dx`` must stay below the 2-D limit 1 / sqrt(2) (:func:`check_courant`) and
:func:`injected_band` gives the band the grid is asked to carry. Used by
:mod:`mapping.simulate.fdtd` and its topic modules.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

from mapping.signal import SonarConfig

_COURANT_LIMIT = 1.0 / math.sqrt(2.0)


# ---- configuration ------------------------------------------------------------------------
@dataclass(frozen=True)
class FdtdConfig:
    """Parameters of the FDTD engine (defaults: paper Table 2, grid fitted to the scene).

    Parameters
    ----------
    grid_step_m : float
        Grid step dx = dy (Table 2: 5 mm).
    time_step_s : float
        Time step dt (Table 2: 8.333 us = 1 / 120 kHz). ``c dt / dx`` must not exceed
        1 / sqrt(2) (2-D Courant limit).
    density_kg_m3 : float
        Density rho_0 of air (Table 2: 1.293).
    sound_speed_m_s : float or None
        c_a; None takes it from the SonarConfig (340 m/s, Table 2).
    pml_cells : int
        Thickness of the graded PML on each outer edge (>= 0; 0 gives a rigid box).
    pml_order : float
        Polynomial grading exponent of the PML absorption profile.
    pml_reflection : float
        Design normal-incidence reflection of the continuous PML, sets sigma_max.
    margin_m : float
        Free space kept around the scene's walls and the path, inside the PML.
    dtype : str
        "float32" (default) or "float64" fields.
    max_frequency_hz : float or None
        Upper edge of the injected band; None: the lower of the signal's band edge
        (carrier + chip rate) and the frequency at ``min_points_per_wavelength``.
    min_points_per_wavelength : float
        Grid limit used when ``max_frequency_hz`` is None.
    warn_points_per_wavelength : float
        Below this many points per wavelength at the injected band edge a warning is issued.
    warmup_s : float or None
        Simulated time before t = 0 so that echoes of the (endless) transmission are present
        from the first sample; None: two domain diagonals of travel time.
    denormal_guard : bool
        Keep fields out of the subnormal range (offset pressure, flush inside the PML).
    """

    grid_step_m: float = 0.005
    time_step_s: float = 1.0 / 120_000.0
    density_kg_m3: float = 1.293
    sound_speed_m_s: float | None = None
    pml_cells: int = 24
    pml_order: float = 3.0
    pml_reflection: float = 1e-6
    margin_m: float = 0.3
    dtype: str = "float32"
    max_frequency_hz: float | None = None
    min_points_per_wavelength: float = 4.0
    warn_points_per_wavelength: float = 10.0
    warmup_s: float | None = None
    denormal_guard: bool = True

    def __post_init__(self) -> None:
        for name in ("grid_step_m", "time_step_s", "density_kg_m3", "min_points_per_wavelength",
                     "pml_order"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"FdtdConfig.{name} must be a positive finite number, got {v!r}")
        if self.sound_speed_m_s is not None and not self.sound_speed_m_s > 0:
            raise ValueError(
                f"FdtdConfig.sound_speed_m_s must be > 0, got {self.sound_speed_m_s}")
        if not (isinstance(self.pml_cells, int) and self.pml_cells >= 0):
            raise ValueError(f"FdtdConfig.pml_cells must be an integer >= 0, got {self.pml_cells}")
        if not 0 < self.pml_reflection < 1:
            raise ValueError(
                f"FdtdConfig.pml_reflection must be in (0, 1), got {self.pml_reflection}")
        if self.margin_m < 0:
            raise ValueError(f"FdtdConfig.margin_m must be >= 0, got {self.margin_m}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(
                f"FdtdConfig.dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if self.max_frequency_hz is not None and not self.max_frequency_hz > 0:
            raise ValueError(
                f"FdtdConfig.max_frequency_hz must be > 0, got {self.max_frequency_hz}")
        if self.warmup_s is not None and not self.warmup_s >= 0:
            raise ValueError(f"FdtdConfig.warmup_s must be >= 0, got {self.warmup_s}")

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dictionary of the fields."""
        return asdict(self)

    def speed(self, sonar: SonarConfig) -> float:
        """The sound speed in use (own value, else the sonar's)."""
        return float(self.sound_speed_m_s or sonar.sound_speed_m_s)


def courant_number(fdtd: FdtdConfig, c: float) -> float:
    """Courant number ``c dt / dx`` (0.567 for Table 2)."""
    return c * fdtd.time_step_s / fdtd.grid_step_m


def check_courant(fdtd: FdtdConfig, c: float) -> float:
    """Return the Courant number; ``ValueError`` above the 2-D limit 1 / sqrt(2)."""
    s = courant_number(fdtd, c)
    if s > _COURANT_LIMIT:
        raise ValueError(
            f"FdtdConfig: Courant number c*time_step_s/grid_step_m = {s:.4f} exceeds the 2-D "
            f"stability limit 1/sqrt(2) = {_COURANT_LIMIT:.4f}; reduce time_step_s below "
            f"{_COURANT_LIMIT * fdtd.grid_step_m / c:.4g} s"
        )
    return s


def injected_band(sonar: SonarConfig, fdtd: FdtdConfig) -> tuple[float, float]:
    """(signal band edge, injected band edge) in Hz."""
    c = fdtd.speed(sonar)
    edge = min(sonar.carrier_hz + sonar.chip_rate_hz, sonar.fs_hz / 2)
    if fdtd.max_frequency_hz is not None:
        return edge, float(fdtd.max_frequency_hz)
    grid_limit = c / (fdtd.min_points_per_wavelength * fdtd.grid_step_m)
    return edge, float(min(edge, grid_limit))
