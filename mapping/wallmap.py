"""The wall map G on a Cartesian grid (paper Sec. 2.2, eq. 5) and its cell geometry."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class WallMap:
    """Accumulated wall evidence G on a regular grid.

    Attributes
    ----------
    G : ndarray, shape (ny, nx)
        Map values; ``G[iy, ix]`` is the cell whose centre is
        ``(origin_m[0] + ix * resolution_m, origin_m[1] + iy * resolution_m)``.
    origin_m : tuple of float
        World coordinates (x, y) in metres of the centre of cell ``G[0, 0]``.
    resolution_m : float
        Cell size in metres (50 mm by default, paper Table 1).
    sonar : str
        JSON of the SonarConfig the map was built with.
    method : str
        Reconstruction method ("paper", ...).
    params : dict
        Method parameters.
    provenance : dict
        Input run files and checksums, block counts.
    """

    G: NDArray[np.float64]
    origin_m: tuple[float, float]
    resolution_m: float
    sonar: str = ""
    method: str = "paper"
    params: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.G.ndim != 2 or min(self.G.shape) < 1:
            raise ValueError(f"WallMap.G must be a non-empty 2-D array, got shape {self.G.shape}")
        if not np.all(np.isfinite(self.G)):
            raise ValueError("WallMap.G contains NaN or inf")
        if not (np.isfinite(self.resolution_m) and self.resolution_m > 0):
            raise ValueError(f"WallMap.resolution_m must be > 0, got {self.resolution_m}")

    @property
    def shape(self) -> tuple[int, int]:
        """(ny, nx)."""
        return (int(self.G.shape[0]), int(self.G.shape[1]))

    @property
    def x_m(self) -> NDArray[np.float64]:
        """Cell-centre x coordinates, shape (nx,)."""
        return np.asarray(self.origin_m[0] + self.resolution_m * np.arange(self.G.shape[1]),
                          dtype=np.float64)

    @property
    def y_m(self) -> NDArray[np.float64]:
        """Cell-centre y coordinates, shape (ny,)."""
        return np.asarray(self.origin_m[1] + self.resolution_m * np.arange(self.G.shape[0]),
                          dtype=np.float64)

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the cell edges, for plotting."""
        h = 0.5 * self.resolution_m
        return (self.x_m[0] - h, self.x_m[-1] + h, self.y_m[0] - h, self.y_m[-1] + h)

    def world_to_cell(self, xy_m: NDArray[np.float64]) -> NDArray[np.float64]:
        """Fractional (ix, iy) cell coordinates of world points ``xy_m`` (..., 2)."""
        xy = np.asarray(xy_m, dtype=np.float64)
        return (xy - np.asarray(self.origin_m)) / self.resolution_m
