"""The Doppler direction-of-arrival heat map (paper Sec. 2.1, eq. 1)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class HeatMap:
    """Polar heat map H[n_theta, n_tau] of one sonar block (paper Fig. 2).

    Attributes
    ----------
    H : ndarray, shape (n_dirs, P)
        Envelope of the Doppler-compensated circular cross-correlation; row n_theta is the
        direction ``angles_rad[n_theta]``, column n_tau the range ``ranges_m[n_tau]``.
    angles_rad : ndarray, shape (n_dirs,)
        Angle of arrival measured from the direction of travel, in [0, pi]; the sensor cannot
        tell +theta from -theta (left/right mirror).
    ranges_m : ndarray, shape (P,)
        One-way range c * n_tau / (2 fs) of each lag.
    speed_m_s : float
        Speed used for the Doppler bank (odometry).
    direction_observable : bool
        False when |speed| is too small for the Doppler bank to separate directions; every
        row is then the same and no bearing may be read from it.
    """

    H: NDArray[np.float64]
    angles_rad: NDArray[np.float64]
    ranges_m: NDArray[np.float64]
    speed_m_s: float
    direction_observable: bool
