"""Rendering of the received signal of the image-source engine over one stretch of samples.

:func:`plan_stretch` traces path validity and solves the retarded delays on coarse grids;
:func:`render_stretch` carries them to every sample (cubic Hermite delay, raised-cosine
gain fades) and sums the paths in the numba kernel of :mod:`mapping.simulate._ism_kernels`.
The numpy twins (:func:`delay_at_samples`, :func:`gain_at_samples`, ``_render_numpy``) and
the per-sample loop :func:`render_reference` are the slow references for tests and
benchmarks; :func:`path_table` gives the ground truth of the paths at a stretch's midpoint.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mapping.signal import TABLE_UPSAMPLE, SonarConfig, periodic_table_at, transmitted_at
from mapping.simulate._base import PathTable, TrajectoryLike
from mapping.simulate.ism._config import IsmConfig, _table, signal_period, spreading_power
from mapping.simulate.ism._delay import retarded_delay, retarded_delay_scalar
from mapping.simulate.ism._images import ImageSet
from mapping.simulate.ism._kernels import _render
from mapping.simulate.ism._paths import PreparedScene, traced_gains
from mapping.simulate.ism._trace import TraceResult

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class StretchPlan:
    """Everything the renderer needs for samples ``start .. start + n - 1``."""

    start_sample: int
    n_samples: int
    images: ImageSet  # candidates at this stretch's validity nodes
    active: NDArray[np.int64]  # image indices with a non-zero gain somewhere in the stretch
    tau: FloatArray
    dtau: FloatArray
    tau_first_node: int
    gain: FloatArray
    gain_first_node: int
    trace: TraceResult
    trace_t_s: FloatArray


def plan_stretch(
    prepared: PreparedScene,
    trajectory: TrajectoryLike,
    config: SonarConfig,
    engine: IsmConfig,
    start_sample: int,
    n_samples: int,
) -> StretchPlan:
    """Trace validity and solve the retarded delays on the coarse grids of one stretch.

    Grid nodes sit at whole multiples of the grid steps from t = 0, so a run cut into
    blocks sees the same nodes as one long stretch (continuity).
    """
    fs = config.fs_hz
    t0, t1 = start_sample / fs, (start_sample + n_samples - 1) / fs
    hv, ht = engine.validity_grid_s, engine.delay_grid_s
    g0 = int(math.floor(t0 / hv)) - 1
    g1 = int(math.floor(t1 / hv)) + 2
    tv = np.arange(g0, g1 + 1, dtype=np.float64) * hv
    images, trace, gains = traced_gains(prepared, trajectory.position(tv), engine.spreading)
    active = np.flatnonzero(np.any(gains != 0.0, axis=1))
    k0 = int(math.floor(t0 / ht)) - 1
    k1 = int(math.floor(t1 / ht)) + 2
    tt = np.arange(k0, k1 + 1, dtype=np.float64) * ht
    A, b = images.A[active], images.b[active]
    tau, dtau = retarded_delay(A, b, trajectory, tt, config.sound_speed_m_s, engine.newton_steps)
    return StretchPlan(
        start_sample=start_sample,
        n_samples=n_samples,
        images=images,
        active=active,
        tau=tau,
        dtau=dtau,
        tau_first_node=k0,
        gain=np.ascontiguousarray(gains[active]),
        gain_first_node=g0,
        trace=trace,
        trace_t_s=tv,
    )


def render_stretch(plan: StretchPlan, config: SonarConfig, engine: IsmConfig) -> FloatArray:
    """Received samples of a planned stretch (numba kernel)."""
    out = np.zeros(plan.n_samples)
    if plan.active.size == 0:
        return out
    half_taps = engine.sinc_half_taps if engine.fractional_delay == "sinc" else 0
    _render(
        plan.start_sample,
        float(config.fs_hz),
        float(config.sound_speed_m_s),
        spreading_power(engine.spreading),
        np.ascontiguousarray(plan.tau),
        np.ascontiguousarray(plan.dtau),
        plan.tau_first_node,
        engine.delay_grid_s,
        plan.gain,
        plan.gain_first_node,
        engine.validity_grid_s,
        engine.fade_s / (2.0 * engine.validity_grid_s),
        _table(config, engine.spreading),
        TABLE_UPSAMPLE,
        np.ascontiguousarray(signal_period(config, engine.spreading)),
        half_taps,
        out,
    )
    return out


def delay_at_samples(plan: StretchPlan, config: SonarConfig, engine: IsmConfig) -> FloatArray:
    """Retarded delay of every active path at every sample of the stretch (n_paths, n).

    Cubic Hermite interpolation of the Newton solutions on the delay grid, with their exact
    time derivatives: the numpy form of what the kernel does per sample.
    """
    absn = plan.start_sample + np.arange(plan.n_samples)
    t = absn / config.fs_hz
    ht = engine.delay_grid_s
    ut = t / ht - plan.tau_first_node
    kt = np.floor(ut).astype(np.int64)
    ft = ut - kt
    h00 = (1 + 2 * ft) * (1 - ft) ** 2
    h10 = ft * (1 - ft) ** 2
    h01 = ft**2 * (3 - 2 * ft)
    h11 = ft**2 * (ft - 1)
    return np.asarray(
        h00 * plan.tau[:, kt]
        + h10 * ht * plan.dtau[:, kt]
        + h01 * plan.tau[:, kt + 1]
        + h11 * ht * plan.dtau[:, kt + 1]
    )


def gain_at_samples(plan: StretchPlan, config: SonarConfig, engine: IsmConfig) -> FloatArray:
    """Gain of every active path at every sample (n_paths, n): the validity grid with
    raised-cosine fades of ``fade_s`` centred between nodes that differ."""
    absn = plan.start_sample + np.arange(plan.n_samples)
    t = absn / config.fs_hz
    hv = engine.validity_grid_s
    ug = t / hv - plan.gain_first_node
    kg = np.floor(ug).astype(np.int64)
    fg = ug - kg
    half = engine.fade_s / (2 * hv)
    ramp = np.clip((fg - (0.5 - half)) / (2 * half), 0.0, 1.0)
    ramp = 0.5 - 0.5 * np.cos(np.pi * ramp)
    g0, g1 = plan.gain[:, kg], plan.gain[:, kg + 1]
    return np.asarray(g0 + (g1 - g0) * ramp)


def _render_numpy(plan: StretchPlan, config: SonarConfig, engine: IsmConfig) -> FloatArray:
    """Plain numpy twin of the kernel (table or windowed sinc), for tests."""
    fs = config.fs_hz
    absn = plan.start_sample + np.arange(plan.n_samples)
    ph = (absn % config.period_samples).astype(np.float64)
    taus = delay_at_samples(plan, config, engine)
    gains = gain_at_samples(plan, config, engine)
    out = np.zeros(plan.n_samples)
    for i in range(plan.active.size):
        amp = (config.sound_speed_m_s * taus[i]) ** (-spreading_power(engine.spreading))
        out += gains[i] * amp * _signal_numpy(ph - taus[i] * fs, config, engine)
    return out


def _signal_numpy(pos: FloatArray, config: SonarConfig, engine: IsmConfig) -> FloatArray:
    """Path signal at fractional sample positions ``pos`` (numpy)."""
    if engine.fractional_delay == "table":
        if engine.spreading == "3d":
            return transmitted_at(pos / config.fs_hz, config)
        return periodic_table_at(_table(config, engine.spreading), pos * TABLE_UPSAMPLE)
    period = signal_period(config, engine.spreading)
    h = engine.sinc_half_taps
    i0 = np.floor(pos).astype(np.int64)
    frac = pos - i0
    acc = np.zeros(pos.shape)
    for m in range(-h + 1, h + 1):
        x = frac - m
        w = 0.42 + 0.5 * np.cos(np.pi * x / h) + 0.08 * np.cos(2 * np.pi * x / h)
        acc += period[(i0 + m) % period.size] * np.sinc(x) * w
    return acc


def render_reference(
    prepared: PreparedScene,
    trajectory: TrajectoryLike,
    config: SonarConfig,
    engine: IsmConfig,
    start_sample: int,
    n_samples: int,
) -> FloatArray:
    """Straightforward per-sample loop: the slow reference for benchmarks and tests.

    For every sample: trace validity at the robot's position then, for every valid path,
    solve the retarded delay by Newton to convergence and evaluate the signal. No grids,
    no interpolation of the delay, no fades (validity switches abruptly).
    """
    fs, c = config.fs_hz, config.sound_speed_m_s
    power = spreading_power(engine.spreading)
    out = np.zeros(n_samples)
    for n in range(n_samples):
        absn = start_sample + n
        t = absn / fs
        x = trajectory.position(np.array([t]))
        images, _, gains_at = traced_gains(prepared, x, engine.spreading)
        gains = gains_at[:, 0]
        acc = 0.0
        for i in np.flatnonzero(gains):
            tau = retarded_delay_scalar(images.A[i], images.b[i], trajectory, t, c)
            pos = np.array([float(absn % config.period_samples) - tau * fs])
            acc += gains[i] * (c * tau) ** (-power) * float(_signal_numpy(pos, config, engine)[0])
        out[n] = acc
    return out


def path_table(
    plan: StretchPlan,
    prepared: PreparedScene,
    trajectory: TrajectoryLike,
    config: SonarConfig,
    engine: IsmConfig,
) -> PathTable:
    """Ground truth of the paths active at the midpoint of a planned stretch."""
    fs = config.fs_hz
    t_mid = (plan.start_sample + plan.n_samples / 2.0) / fs
    j = int(np.argmin(np.abs(plan.trace_t_s - t_mid)))
    idx = plan.active[plan.trace.valid[plan.active, j]]
    A, b = plan.images.A[idx], plan.images.b[idx]
    tau, dtau = retarded_delay(
        A, b, trajectory, np.array([t_mid]), config.sound_speed_m_s, engine.newton_steps
    )
    x = trajectory.position(np.array([t_mid]))[0]
    v = trajectory.velocity(np.array([t_mid]))[0]
    arrive = (A @ x + b) - x
    speed = float(np.linalg.norm(v))
    if speed > 0:
        cosang = arrive @ v / (np.linalg.norm(arrive, axis=1) * speed)
        angle = np.arccos(np.clip(cosang, -1.0, 1.0))
    else:
        angle = np.full(idx.size, np.nan)
    refl = plan.trace.reflection[idx, j]
    walls = plan.trace.walls[idx, j]
    amp = refl * (config.sound_speed_m_s * tau[:, 0]) ** (-spreading_power(engine.spreading))
    return PathTable(
        order=plan.trace.order[idx, j].astype(np.int64),
        walls=tuple(tuple(int(w) for w in row if w >= 0) for row in walls),
        delay_s=tau[:, 0],
        doppler_factor=1.0 - dtau[:, 0],
        angle_to_velocity_rad=angle,
        reflection=refl,
        amplitude=amp,
    )
