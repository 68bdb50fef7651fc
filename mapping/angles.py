"""Angles, circular statistics and pose errors: the one home of these helpers.

Every package that wraps a heading, averages angles or compares two poses imports them from
here (``localization`` may import ``mapping``, never the reverse, so they live in ``mapping``).
Poses are ``(x_m, y_m, heading_rad)`` rows; headings follow ROS REP-103 (counter-clockwise
from +x, wrapped to (-pi, pi]).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def wrap_angle(theta_rad: ArrayLike) -> FloatArray:
    """Wrap angles to (-pi, pi] (ROS REP-103 yaw); exact for inputs already in range.

    ``theta - 2 pi round(theta / 2 pi)`` leaves |theta| <= pi untouched (no ``+ pi - pi``
    round-off) and the two boundary fixes keep -pi out of the result even when rounding
    lands on it (the float just above pi used to come back as -pi).
    """
    th = np.asarray(theta_rad, dtype=np.float64)
    w = th - 2.0 * np.pi * np.round(th / (2.0 * np.pi))
    w = np.where(w <= -np.pi, w + 2.0 * np.pi, w)
    return np.asarray(np.where(w > np.pi, w - 2.0 * np.pi, w))


def circular_mean(angles: FloatArray, weights: FloatArray | None = None) -> float:
    """Weighted circular mean in (-pi, pi]."""
    w = np.ones_like(angles) if weights is None else weights
    return float(wrap_angle(math.atan2(float(np.sum(w * np.sin(angles))),
                                       float(np.sum(w * np.cos(angles))))))


def circular_std(angles: FloatArray, weights: FloatArray | None = None) -> float:
    """Circular standard deviation ``sqrt(-2 ln R)`` (rad) of weighted angles."""
    w = np.ones_like(angles) if weights is None else weights
    w = w / w.sum()
    r = math.hypot(float(np.sum(w * np.sin(angles))), float(np.sum(w * np.cos(angles))))
    return math.sqrt(-2.0 * math.log(max(r, 1e-300)))


def mean_resultant(angles: FloatArray, weights: FloatArray | None = None) -> tuple[float, float]:
    """Circular mean of ``angles`` (in [-pi, pi]) and the mean resultant length R in [0, 1].

    The two numbers the posterior summaries need together; :func:`circular_std_of_resultant`
    turns R into a spread. (The weights are normalized before the sums, so the mean may differ
    from :func:`circular_mean` in the last bit.)
    """
    w = np.ones_like(angles) if weights is None else np.asarray(weights, dtype=np.float64)
    c = float(np.sum(w * np.cos(angles)) / np.sum(w))
    s = float(np.sum(w * np.sin(angles)) / np.sum(w))
    return math.atan2(s, c), math.hypot(c, s)


def circular_std_of_resultant(resultant_length: float) -> float:
    """Circular standard deviation ``sqrt(-2 ln R)`` in radians of a mean resultant length
    (inf for R = 0)."""
    return math.sqrt(-2.0 * math.log(resultant_length)) if resultant_length > 0 else math.inf


def pose_error(estimate: ArrayLike, truth: ArrayLike) -> tuple[float, float]:
    """Position error (m) and absolute wrapped heading error (rad) of one pose."""
    e = np.asarray(estimate, dtype=np.float64)
    t = np.asarray(truth, dtype=np.float64)
    return (float(math.hypot(e[0] - t[0], e[1] - t[1])),
            float(abs(wrap_angle(e[2] - t[2]))))


def pose_difference(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """``a - b`` for poses (..., 3), the heading difference wrapped to (-pi, pi]."""
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    d[..., 2] = wrap_angle(d[..., 2])
    return d
