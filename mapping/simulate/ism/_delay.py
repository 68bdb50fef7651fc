"""Retarded delay of image sources heard by the moving monostatic sonar.

The microphone at time ``t`` hears what the image (the robot mirrored through the walls,
``A x + b``) emitted at ``t - tau``; the delay solves

    | x(t) - (A x(t - tau) + b) | = c tau

by Newton's method, with its exact time derivative (the Doppler time compression is
``1 - d tau / dt``). :func:`retarded_delay` is vectorised over images and times;
:func:`retarded_delay_scalar` iterates one image at one time to convergence (reference).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mapping.simulate._base import TrajectoryLike

FloatArray = NDArray[np.float64]


def retarded_delay(
    A: FloatArray,
    b: FloatArray,
    trajectory: TrajectoryLike,
    t_s: FloatArray,
    c: float,
    newton_steps: int = 3,
) -> tuple[FloatArray, FloatArray]:
    """Retarded delay of image sources heard by the moving robot, and its time derivative.

    Solves ``F(t, tau) = |x(t) - A x(t - tau) - b| - c tau = 0`` by Newton's method from the
    static delay ``|x(t) - A x(t) - b| / c``; ``d tau / dt = -F_t / F_tau``.

    Parameters
    ----------
    A, b : ndarray, shapes (n, 2, 2) and (n, 2)
        Image maps.
    trajectory : TrajectoryLike
    t_s : ndarray, shape (m,)
        Reception times.
    c : float
        Sound speed in m/s.
    newton_steps : int

    Returns
    -------
    tau : ndarray, shape (n, m)
        Delay in seconds.
    dtau_dt : ndarray, shape (n, m)
        Its derivative; the Doppler time-compression factor is ``1 - dtau_dt``.
    """
    t = np.asarray(t_s, dtype=np.float64).ravel()
    n, m = A.shape[0], t.size
    x_rx = trajectory.position(t)  # (m, 2)
    v_rx = trajectory.velocity(t)
    img0 = x_rx[None] @ A.transpose(0, 2, 1) + b[:, None, :]
    tau = np.linalg.norm(x_rx[None] - img0, axis=2) / c
    for _ in range(newton_steps):
        d, av = _leg(A, b, trajectory, t, tau, x_rx)
        dist = np.linalg.norm(d, axis=2)
        f = dist - c * tau
        fprime = np.sum(d * av, axis=2) / dist - c
        tau = tau - f / fprime
    d, av = _leg(A, b, trajectory, t, tau, x_rx)
    dist = np.linalg.norm(d, axis=2)
    f_tau = np.sum(d * av, axis=2) / dist - c
    f_t = np.sum(d * (v_rx[None] - av), axis=2) / dist
    return tau.reshape(n, m), (-f_t / f_tau).reshape(n, m)


def _leg(
    A: FloatArray,
    b: FloatArray,
    trajectory: TrajectoryLike,
    t: FloatArray,
    tau: FloatArray,
    x_rx: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Vector receiver - image at emission time, and the image velocity A v(t - tau)."""
    te = (t[None, :] - tau).ravel()
    xe = trajectory.position(te).reshape(tau.shape + (2,))
    ve = trajectory.velocity(te).reshape(tau.shape + (2,))
    img = xe @ A.transpose(0, 2, 1) + b[:, None, :]
    av = ve @ A.transpose(0, 2, 1)
    return x_rx[None] - img, av


def retarded_delay_scalar(
    A: FloatArray, b: FloatArray, trajectory: TrajectoryLike, t_s: float, c: float
) -> float:
    """Retarded delay of one image at one time, Newton iterated to convergence (reference)."""
    x = trajectory.position(np.array([t_s]))[0]
    tau = float(np.linalg.norm(x - A @ x - b)) / c
    for _ in range(50):
        xe = trajectory.position(np.array([t_s - tau]))[0]
        ve = trajectory.velocity(np.array([t_s - tau]))[0]
        d = x - A @ xe - b
        dist = float(np.linalg.norm(d))
        step = (dist - c * tau) / (float(d @ (A @ ve)) / dist - c)
        tau -= step
        if abs(step) < 1e-16:
            break
    return tau
