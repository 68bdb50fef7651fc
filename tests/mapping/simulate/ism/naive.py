"""Plain numpy twin of the numba kernel of :mod:`mapping.simulate.ism` and the per-sample
reference loop (tests and benchmarks only; ``benchmarks/simulate_ism.py`` times the loop).

:func:`render_numpy` does what ``_kernels._render`` does over a planned stretch, from
:func:`delay_at_samples` and :func:`gain_at_samples` (the kernel's per-sample delay and gain,
vectorized); :func:`render_reference` needs no plan: validity traced and the retarded delay
solved by Newton at every sample, no grids, no fades. ``test_ism.py`` compares them with
:func:`mapping.simulate.ism.render_stretch`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from mapping.signal import (
    TABLE_UPSAMPLE,
    SonarConfig,
    periodic_table,
    periodic_table_at,
    transmitted_at,
)
from mapping.simulate import TrajectoryLike
from mapping.simulate.ism import (
    IsmConfig,
    PreparedScene,
    StretchPlan,
    retarded_delay_scalar,
    signal_period,
    spreading_power,
    traced_gains,
)

FloatArray = NDArray[np.float64]


@lru_cache(maxsize=8)
def _table(config: SonarConfig, spreading: str) -> FloatArray:
    """The kernel's signal table: the band-limited interpolant of one period, 32x finer."""
    period = signal_period(config, spreading)
    return periodic_table(np.fft.rfft(period), period.size)


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


def render_numpy(plan: StretchPlan, config: SonarConfig, engine: IsmConfig) -> FloatArray:
    """Twin of ``_kernels._render`` over a planned stretch (table or windowed sinc)."""
    fs = config.fs_hz
    absn = plan.start_sample + np.arange(plan.n_samples)
    ph = (absn % config.period_samples).astype(np.float64)
    taus = delay_at_samples(plan, config, engine)
    gains = gain_at_samples(plan, config, engine)
    out = np.zeros(plan.n_samples)
    for i in range(plan.active.size):
        amp = (config.sound_speed_m_s * taus[i]) ** (-spreading_power(engine.spreading))
        out += gains[i] * amp * signal_numpy(ph - taus[i] * fs, config, engine)
    return out


def signal_numpy(pos: FloatArray, config: SonarConfig, engine: IsmConfig) -> FloatArray:
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
            acc += gains[i] * (c * tau) ** (-power) * float(signal_numpy(pos, config, engine)[0])
        out[n] = acc
    return out
