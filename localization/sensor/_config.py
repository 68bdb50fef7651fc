"""Parameters of the sensor model (:class:`SensorConfig`); see :mod:`localization.sensor`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
Model = Literal["correlation", "range"]


@dataclass(frozen=True)
class SensorConfig:
    """Parameters of the sensor model.

    Parameters
    ----------
    model : {"correlation", "range"}
        Full polar correlation, or range-only. "correlation" still falls back to "range"
        for a block without direction information (see ``min_speed_m_s``).
    n_angles : int
        Directions of the full-circle polar grid (72 = 5 deg); also the grid filter's
        heading bins.
    range_step_m, min_range_m, max_range_m : float
        Range bins ``min_range_m + k * range_step_m`` below ``max_range_m``.
    n_headings : int
        Heading bins of the direction table (1 deg by default); a multiple of ``n_angles``.
    beta : float
        Sharpness: log-likelihood ``beta * (rho - 1)`` before the floor.
    z_rand : float
        Weight of the uniform floor in (0, 1).
    min_speed_m_s : float
        At ``|speed|`` below this the range-only model is used automatically.
    map_blur_cells : float
        Gaussian blur (standard deviation, cells) applied to G before sampling.
    range_gain_exponent : float
        The measured heat map is multiplied by ``r ** range_gain_exponent`` to undo the
        spreading loss before it is compared with G.
    keep_fraction : float
        Share of the unfolded measurement kept above the noise floor: the
        ``1 - keep_fraction`` quantile is subtracted and negatives set to 0, so the cross
        term of the correlation is a sparse dot product.
    """

    model: Model = "correlation"
    n_angles: int = 72
    range_step_m: float = 0.05
    min_range_m: float = 0.15
    max_range_m: float = 5.0
    n_headings: int = 360
    beta: float = 200.0
    z_rand: float = 0.001
    min_speed_m_s: float = 0.03
    map_blur_cells: float = 1.0
    range_gain_exponent: float = 1.0
    keep_fraction: float = 0.10

    def __post_init__(self) -> None:
        if self.model not in ("correlation", "range"):
            raise ValueError(f"model must be 'correlation' or 'range', got {self.model!r}")
        if not 8 <= self.n_angles <= 720 or self.n_angles % 2:
            raise ValueError(f"n_angles must be even in [8, 720], got {self.n_angles}")
        if self.n_headings < self.n_angles or self.n_headings % self.n_angles:
            raise ValueError(
                f"n_headings must be a multiple of n_angles={self.n_angles}, got "
                f"{self.n_headings}"
            )
        if not 0 < self.range_step_m <= 1.0:
            raise ValueError(f"range_step_m must be in (0, 1] m, got {self.range_step_m}")
        if not 0 <= self.min_range_m < self.max_range_m - self.range_step_m:
            raise ValueError(
                "need 0 <= min_range_m < max_range_m - range_step_m, got "
                f"{self.min_range_m}, {self.max_range_m}"
            )
        if not (math.isfinite(self.beta) and self.beta > 0):
            raise ValueError(f"beta must be > 0, got {self.beta}")
        if not 0 < self.z_rand < 1:
            raise ValueError(f"z_rand must be in (0, 1), got {self.z_rand}")
        if not self.min_speed_m_s >= 0:
            raise ValueError(f"min_speed_m_s must be >= 0, got {self.min_speed_m_s}")
        if not 0 < self.keep_fraction <= 1:
            raise ValueError(f"keep_fraction must be in (0, 1], got {self.keep_fraction}")
        if not self.map_blur_cells >= 0:
            raise ValueError(f"map_blur_cells must be >= 0, got {self.map_blur_cells}")

    @property
    def ranges_m(self) -> FloatArray:
        """Centres of the range bins, shape (n_r,)."""
        n_r = int(math.floor((self.max_range_m - self.min_range_m) / self.range_step_m))
        return np.asarray(self.min_range_m + self.range_step_m * np.arange(n_r),
                          dtype=np.float64)

    @property
    def angles_rad(self) -> FloatArray:
        """Polar directions relative to the heading, wrapped to (-pi, pi], shape (n_angles,)."""
        a = 2.0 * np.pi * np.arange(self.n_angles) / self.n_angles
        return np.where(a > np.pi, a - 2.0 * np.pi, a)
