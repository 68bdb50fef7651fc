"""Odometry motion model (paper Fig. 1(b): wheel encoders between sonar blocks).

A pose is ``(x_m, y_m, heading_rad)`` with the heading the robot's facing direction (ROS
REP-103 yaw, which is the direction of travel when driving forward). Odometry reports, per
block, the speed along the heading and the yaw rate; over a time step ``dt_s`` the robot
follows an arc. The arc is decomposed the way the classic odometry model does it
(Thrun, Burgard, Fox, *Probabilistic Robotics*, Table 5.6; ROS AMCL's ``alpha1..alpha4``):
a first rotation ``rot1``, a straight translation ``trans`` (the chord of the arc) and a
second rotation ``rot2``. Each part gets zero-mean Gaussian noise whose variance grows with
the motion itself, so a robot that does not move accumulates no uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mapping.angles import wrap_angle

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class MotionNoise:
    """Noise coefficients of the odometry model (AMCL's ``odom_alpha1..4``).

    The defaults (translation std 7 % of the distance, rotation std 11 % of the distance in
    rad/m) were calibrated with the sensor's ``beta`` on simulated runs with 0.005 m/s
    odometry speed noise (benchmarks/localization_bench.py); a real robot may need more.

    Parameters
    ----------
    alpha1 : float
        Rotation variance per squared rotation (rad^2 / rad^2).
    alpha2 : float
        Rotation variance per squared translation (rad^2 / m^2).
    alpha3 : float
        Translation variance per squared translation (m^2 / m^2).
    alpha4 : float
        Translation variance per squared rotation (m^2 / rad^2).
    min_trans_std_m : float
        Standard deviation added to the translation of every step with ``dt_s > 0``; keeps a
        particle set from collapsing onto one point (0 disables).
    min_rot_std_rad : float
        Same floor for the two rotations.
    """

    alpha1: float = 0.005
    alpha2: float = 0.0125
    alpha3: float = 0.005
    alpha4: float = 0.0005
    min_trans_std_m: float = 0.005
    min_rot_std_rad: float = 0.005

    def __post_init__(self) -> None:
        for name in ("alpha1", "alpha2", "alpha3", "alpha4", "min_trans_std_m",
                     "min_rot_std_rad"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"MotionNoise.{name} must be finite and >= 0, got {value}")


def odometry_increment(
    speed_m_s: float, yaw_rate_rad_s: float, dt_s: float
) -> tuple[float, float, float]:
    """Decompose an arc of constant speed and yaw rate into ``(rot1, trans, rot2)``.

    Parameters
    ----------
    speed_m_s : float
        Speed along the heading (negative when reversing).
    yaw_rate_rad_s : float
        Yaw rate (counter-clockwise positive).
    dt_s : float
        Duration of the step, >= 0.

    Returns
    -------
    rot1, trans, rot2 : float
        The arc's chord has signed length ``trans`` (negative when reversing) and makes the
        angle ``rot1`` with the initial heading; ``rot1 + rot2`` is the total rotation
        ``yaw_rate * dt``. For a straight line ``rot1 = rot2 = 0``.
    """
    _check_odometry(speed_m_s, yaw_rate_rad_s, dt_s)
    dtheta = yaw_rate_rad_s * dt_s
    if abs(dtheta) < 1e-9:
        chord = speed_m_s * dt_s
    else:
        chord = 2.0 * speed_m_s / yaw_rate_rad_s * math.sin(0.5 * dtheta)
    return 0.5 * dtheta, chord, 0.5 * dtheta


def _check_odometry(speed_m_s: float, yaw_rate_rad_s: float, dt_s: float) -> None:
    if not math.isfinite(speed_m_s) or abs(speed_m_s) > 10.0:
        raise ValueError(f"speed_m_s must be finite with |speed| <= 10 m/s, got {speed_m_s}")
    if not math.isfinite(yaw_rate_rad_s) or abs(yaw_rate_rad_s) > 20.0:
        raise ValueError(
            f"yaw_rate_rad_s must be finite with |yaw rate| <= 20 rad/s, got {yaw_rate_rad_s}"
        )
    if not math.isfinite(dt_s) or not 0.0 <= dt_s <= 60.0:
        raise ValueError(f"dt_s must be in [0, 60] s, got {dt_s}")


def motion_std(
    rot1: float, trans: float, rot2: float, noise: MotionNoise
) -> tuple[float, float, float]:
    """Standard deviations of ``(rot1, trans, rot2)`` under ``noise`` (Thrun Table 5.6)."""
    moving = abs(trans) > 0 or abs(rot1) > 0 or abs(rot2) > 0
    floor_t = noise.min_trans_std_m if moving else 0.0
    floor_r = noise.min_rot_std_rad if moving else 0.0
    s_rot1 = math.sqrt(noise.alpha1 * rot1**2 + noise.alpha2 * trans**2 + floor_r**2)
    s_trans = math.sqrt(
        noise.alpha3 * trans**2 + noise.alpha4 * (rot1**2 + rot2**2) + floor_t**2
    )
    s_rot2 = math.sqrt(noise.alpha1 * rot2**2 + noise.alpha2 * trans**2 + floor_r**2)
    return s_rot1, s_trans, s_rot2


def apply_increment(
    poses: FloatArray, rot1: FloatArray | float, trans: FloatArray | float,
    rot2: FloatArray | float,
) -> FloatArray:
    """Move ``poses`` (n, 3) by ``rot1``, then ``trans`` along the new heading, then ``rot2``."""
    h1 = poses[:, 2] + rot1
    out = np.empty_like(poses)
    out[:, 0] = poses[:, 0] + trans * np.cos(h1)
    out[:, 1] = poses[:, 1] + trans * np.sin(h1)
    out[:, 2] = wrap_angle(h1 + rot2)
    return out


def predict(
    poses: FloatArray,
    speed_m_s: float,
    yaw_rate_rad_s: float,
    dt_s: float,
    noise: MotionNoise,
    rng: np.random.Generator,
) -> FloatArray:
    """Sample the motion model for every pose: the particle filter's prediction step.

    Parameters
    ----------
    poses : ndarray, shape (n, 3)
        x_m, y_m, heading_rad of each particle.
    speed_m_s, yaw_rate_rad_s : float
        Odometry over the step.
    dt_s : float
        Step duration (the block length, or 0 for no motion).
    noise : MotionNoise
        Noise coefficients.
    rng : numpy.random.Generator
        Source of randomness.

    Returns
    -------
    ndarray, shape (n, 3)
        New poses (a new array; ``poses`` is not modified), heading wrapped to (-pi, pi].

    Raises
    ------
    ValueError
        If the odometry is not finite or out of range, or ``poses`` is not (n, 3).
    """
    poses = _check_poses(poses)
    rot1, trans, rot2 = odometry_increment(speed_m_s, yaw_rate_rad_s, dt_s)
    s1, st, s2 = motion_std(rot1, trans, rot2, noise)
    n = poses.shape[0]
    z = rng.standard_normal((3, n))
    return apply_increment(poses, rot1 + s1 * z[0], trans + st * z[1], rot2 + s2 * z[2])


def predict_mean(
    pose: FloatArray, speed_m_s: float, yaw_rate_rad_s: float, dt_s: float
) -> FloatArray:
    """Noise-free motion of one pose (3,): dead reckoning."""
    rot1, trans, rot2 = odometry_increment(speed_m_s, yaw_rate_rad_s, dt_s)
    return apply_increment(_check_poses(np.asarray(pose, dtype=np.float64)[None, :]),
                           rot1, trans, rot2)[0]


def _check_poses(poses: FloatArray) -> FloatArray:
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must have shape (n, 3), got {poses.shape}")
    return poses
