"""Rendering of the received signal of the image-source engine over one stretch of samples.

:func:`plan_stretch` traces path validity and solves the retarded delays on coarse grids;
:func:`render_stretch` carries them to every sample (cubic Hermite delay, raised-cosine
gain fades) and sums the paths in the numba kernel of :mod:`mapping.simulate.ism._kernels`;
:func:`path_table` gives the ground truth of the paths at a stretch's midpoint. The numpy
twin of the kernel and the slow per-sample reference loop live with the tests
(``tests/mapping/simulate/ism/naive.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from mapping.signal import TABLE_UPSAMPLE, SonarConfig
from mapping.simulate._base import PathTable, TrajectoryLike
from mapping.simulate.ism._config import (
    IsmConfig,
    _diffraction_table,
    _table,
    diffraction_period,
    signal_period,
    spreading_power,
)
from mapping.simulate.ism._delay import retarded_delay
from mapping.simulate.ism._diffraction import (
    EdgePaths,
    edge_delay,
    edge_gains,
    edge_validity,
    kept_gains,
)
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
    edge_active: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    edge_tau: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    edge_dtau: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    edge_gain: NDArray[np.complex128] = field(default_factory=lambda: np.zeros((0, 0), complex))
    edge_gain_flat: NDArray[np.complex128] = field(
        default_factory=lambda: np.zeros((0, 0), complex))


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
    plan = StretchPlan(
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
    if prepared.edges is None or prepared.edges.n == 0:
        return plan
    return _with_edges(plan, prepared, prepared.edges, trajectory, config, engine, tt)


def _with_edges(plan: StretchPlan, prepared: PreparedScene, edges: EdgePaths,
                trajectory: TrajectoryLike, config: SonarConfig, engine: IsmConfig,
                tt: FloatArray) -> StretchPlan:
    """The plan with the edge-diffracted paths' gains (validity nodes) and delays."""
    pos = trajectory.position(plan.trace_t_s)
    c = config.sound_speed_m_s
    valid = edge_validity(edges, prepared.segments, pos)
    gains, flat = edge_gains(edges, valid, prepared.reflection, pos, config)
    keep = kept_gains(edges, np.abs(gains) + np.abs(flat), pos,
                      spreading_power(engine.spreading), prepared.max_path_m,
                      prepared.amplitude_floor)
    gains, flat = np.where(keep, gains, 0.0), np.where(keep, flat, 0.0)
    active = np.flatnonzero(np.any(keep, axis=1))
    sub = EdgePaths(edges.wedge[active], edges.A_in[active], edges.b_in[active],
                    edges.A_out[active], edges.b_out[active], edges.via[active], edges.wedges)
    tau, dtau = edge_delay(sub, trajectory, tt, c, engine.newton_steps)
    return replace(plan, edge_active=active, edge_tau=tau, edge_dtau=dtau,
                   edge_gain=np.ascontiguousarray(gains[active]),
                   edge_gain_flat=np.ascontiguousarray(flat[active]))


def render_stretch(plan: StretchPlan, config: SonarConfig, engine: IsmConfig) -> FloatArray:
    """Received samples of a planned stretch (numba kernel)."""
    out = np.zeros(plan.n_samples)
    half_taps = engine.sinc_half_taps if engine.fractional_delay == "sinc" else 0
    if plan.edge_active.size:
        out += _edge_samples(plan, config, engine, half_taps)
    if plan.active.size == 0:
        return out
    specular = np.zeros(plan.n_samples)
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
        specular,
    )
    return out + specular


def _edge_samples(plan: StretchPlan, config: SonarConfig, engine: IsmConfig,
                  half_taps: int) -> FloatArray:
    """The diffracted paths' samples: each complex gain (Keller part, boundary part) as its
    real part with the signal and its imaginary part with the quadrature, spreading power
    ``p + 1/2``."""
    total = np.zeros(plan.n_samples)
    for keller, gains in ((True, plan.edge_gain), (False, plan.edge_gain_flat)):
        for quadrature in (False, True):
            gain = np.ascontiguousarray(gains.imag if quadrature else gains.real)
            if not np.any(gain):
                continue
            out = np.zeros(plan.n_samples)
            _render(
                plan.start_sample,
                float(config.fs_hz),
                float(config.sound_speed_m_s),
                spreading_power(engine.spreading) + 0.5,
                np.ascontiguousarray(plan.edge_tau),
                np.ascontiguousarray(plan.edge_dtau),
                plan.tau_first_node,
                engine.delay_grid_s,
                gain,
                plan.gain_first_node,
                engine.validity_grid_s,
                engine.fade_s / (2.0 * engine.validity_grid_s),
                _diffraction_table(config, engine.spreading, keller, quadrature),
                TABLE_UPSAMPLE,
                np.ascontiguousarray(
                    diffraction_period(config, engine.spreading, keller, quadrature)),
                half_taps,
                out,
            )
            total += out
    return total


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
