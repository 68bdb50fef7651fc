"""The raw recording, chunk by chunk: render at the sonar rate, filter, resample, add noise.

For each chunk of recording samples ``n0 .. n1 - 1`` (sonar times
``tau_n = n / (fs_rec (1 + ppm 1e-6)) - latency``) the sonar-rate stream is extended up to the
last sonar sample the resampling filter reaches: wall echoes (the image-source engine's
:func:`~mapping.simulate.ism.render_stretch`), their floor/ceiling combinations, the direct
wave and the pure vertical bounces (silent before sonar sample 0, the playback onset), passed
through the loudspeaker's and the microphone's band-passes (causal, their state carried from
chunk to chunk). :func:`mapping.resample.resample_at` then reads it at the ``tau_n``;
samples before the onset are zeroed (noise only), white noise is added and the result
clipped to full scale.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.signal import sosfilt, sosfilt_zi

from mapping.recording import PoseLog
from mapping.resample import resample_at
from mapping.signal import SonarConfig, sound_speed_at, transmitted_at
from mapping.simulate._base import SceneLike, TrajectoryLike
from mapping.simulate.ism import (
    IsmConfig,
    PreparedScene,
    plan_stretch,
    prepare_scene,
    render_stretch,
)
from mapping.simulate.raw._config import RawConfig
from mapping.simulate.raw._paths import band_sos, static_paths, vertical_images, vertical_plan

FloatArray = NDArray[np.float64]

#: Half length of the sonar -> recording resampling filter: the sonar stream has energy up
#: to its Nyquist frequency, so a long filter (transition ~0.8 kHz at 40 kHz) keeps the
#: error of a 40 -> 48 kHz recording at 2e-3 of the peak (9e-4 RMS; 64 taps: 5e-3).
RESAMPLE_HALF_TAPS = 128


@dataclass(frozen=True)
class RawTruth:
    """What the simulator put in, for checking an importer.

    ``sound_speed_m_s`` is the propagation speed used; ``onset_sample`` the first recording
    sample at or after the playback onset (tau >= 0); ``static_delay_s`` / ``static_gain``
    the direct wave (first, when ``direct_delay_s`` is not None) and the pure vertical
    bounces; ``noise_sigma`` the noise standard deviation of each chunk.
    """

    latency_s: float
    clock_offset_ppm: float
    sound_speed_m_s: float
    onset_sample: int
    direct_delay_s: float | None
    static_delay_s: FloatArray
    static_gain: FloatArray
    noise_sigma: FloatArray
    clipped_samples: int


@dataclass(frozen=True)
class RawChunk:
    """Recording samples ``start_sample .. start_sample + samples.size - 1`` and the noise
    level they got."""

    start_sample: int
    samples: FloatArray
    noise_sigma: float
    clipped_samples: int


@dataclass(frozen=True)
class RawRecording:
    """A simulated raw recording: samples at ``fs_hz`` (float64), the pose log on the
    recording clock, the configuration and the ground truth."""

    samples: FloatArray
    fs_hz: float
    poses: PoseLog
    raw: RawConfig
    truth: RawTruth


def recording_times(raw: RawConfig, first: int, n_samples: int) -> FloatArray:
    """Sonar times (s) of recording samples ``first .. first + n_samples - 1``:
    ``tau_n = n / (fs_rec (1 + ppm 1e-6)) - latency``."""
    n = first + np.arange(n_samples, dtype=np.float64)
    return n / (raw.fs_hz * (1.0 + raw.clock_offset_ppm * 1e-6)) - raw.latency_s


def propagation_speed(config: SonarConfig, raw: RawConfig) -> float:
    """Speed of sound (m/s) the echoes travel at: from ``raw.temperature_c`` if given."""
    return config.sound_speed_m_s if raw.temperature_c is None else sound_speed_at(
        raw.temperature_c)


def pose_log(trajectory: TrajectoryLike, raw: RawConfig, duration_s: float) -> PoseLog:
    """Rows every ``raw.pose_step_s`` on the recording clock from 0 to at least
    ``duration_s``: the pose at sonar time ``tau = t_rec / (1 + ppm 1e-6) - latency``."""
    n_rows = int(math.ceil(duration_s / raw.pose_step_s)) + 1
    t_rec = np.arange(max(n_rows, 2), dtype=np.float64) * raw.pose_step_s
    tau = t_rec / (1.0 + raw.clock_offset_ppm * 1e-6) - raw.latency_s
    pose = np.asarray(trajectory.pose(tau), dtype=np.float64)
    return PoseLog(t_s=np.asarray(t_rec, dtype=np.float64), x_m=pose[:, 0].copy(),
                   y_m=pose[:, 1].copy(), heading_rad=pose[:, 2].copy(),
                   speed_m_s=np.asarray(trajectory.speed_m_s(tau), dtype=np.float64))


def resample_cutoff_hz(config: SonarConfig, raw: RawConfig) -> float:
    """Low-pass of the sonar -> recording resampling: half the lower of the two rates."""
    return 0.5 * min(config.fs_hz, raw.fs_hz)


def check_engine(engine: IsmConfig) -> None:
    """``ValueError`` for engine settings the raw simulator does not model."""
    if engine.spreading != "3d":
        raise ValueError(f"IsmConfig.spreading must be '3d' for a raw recording (a real room), "
                         f"got {engine.spreading!r}")
    if engine.snr_db is not None:
        raise ValueError("IsmConfig.snr_db must be None for a raw recording; use RawConfig.snr_db")
    if engine.rt60_s is not None:
        raise ValueError("IsmConfig.rt60_s must be None: the raw simulator has no reverberant tail")
    if engine.odometry_noise_m_s != 0.0:
        raise ValueError(
            "IsmConfig.odometry_noise_m_s must be 0: the raw simulator logs true poses")


@dataclass
class _SonarStream:
    """The filtered sonar-rate stream, extended on demand (state carried across chunks)."""

    prepared: PreparedScene
    trajectory: TrajectoryLike
    config: SonarConfig  # with the propagation speed
    engine: IsmConfig
    raw: RawConfig
    filters: list[tuple[FloatArray, FloatArray]]  # (sos, zi)
    start: int = 0  # sonar sample index of buffer[0]
    buffer: FloatArray = field(default_factory=lambda: np.zeros(0))
    walls: FloatArray = field(default_factory=lambda: np.zeros(0))  # unfiltered wall echoes

    @property
    def end(self) -> int:
        """First sonar sample not yet rendered."""
        return self.start + self.buffer.size

    def extend_to(self, last: int) -> None:
        """Render, filter and append sonar samples up to ``last`` (inclusive)."""
        first = self.end
        if last < first:
            return
        walls, other = _render_sonar(self, first, last - first + 1)
        mixed = walls + other
        for i, (sos, zi) in enumerate(self.filters):
            mixed, zi = sosfilt(sos, mixed, zi=zi)
            self.filters[i] = (sos, zi)
        self.buffer = np.concatenate([self.buffer, mixed])
        self.walls = np.concatenate([self.walls, walls])

    def drop_before(self, first: int) -> None:
        """Forget samples before sonar sample ``first``."""
        k = min(max(first - self.start, 0), self.buffer.size)
        self.buffer, self.walls, self.start = self.buffer[k:], self.walls[k:], self.start + k

    def echo_power(self, first: int, last: int) -> float:
        """Mean square of the unfiltered wall echoes over sonar samples first..last."""
        seg = self.walls[max(first - self.start, 0): max(last + 1 - self.start, 0)]
        return float(np.mean(seg**2)) if seg.size else 0.0


def _render_sonar(stream: _SonarStream, first: int, n: int) -> tuple[FloatArray, FloatArray]:
    """Wall echoes and everything else (vertical, direct) at sonar samples first..first+n-1;
    zero before sample 0 (the playback onset)."""
    walls, other = np.zeros(n), np.zeros(n)
    lead = max(-first, 0)
    if lead >= n:
        return walls, other
    cfg, raw = stream.config, stream.raw
    start, count = first + lead, n - lead
    plan = plan_stretch(stream.prepared, stream.trajectory, cfg, stream.engine, start, count)
    walls[lead:] = render_stretch(plan, cfg, stream.engine)
    c = cfg.sound_speed_m_s
    if raw.vertical_order == 2:
        for dz, r in zip(*vertical_images(raw), strict=True):
            if plan.active.size:
                other[lead:] += render_stretch(vertical_plan(plan, dz, r, c), cfg, stream.engine)
    t = (start + np.arange(count)) / cfg.fs_hz
    for delay, gain in zip(*static_paths(raw, c), strict=True):
        other[lead:] += gain * transmitted_at(t - delay, cfg)
    return walls, other


def _filters(config: SonarConfig, raw: RawConfig) -> list[tuple[FloatArray, FloatArray]]:
    """(sos, zero state) of the loudspeaker's then the microphone's band-pass."""
    out = []
    for band in (raw.speaker_band_hz, raw.mic_band_hz):
        if band is not None:
            sos = band_sos(band, raw.band_order, config.fs_hz)
            out.append((sos, sosfilt_zi(sos) * 0.0))
    return out


def iter_raw_chunks(
    scene: SceneLike,
    trajectory: TrajectoryLike,
    config: SonarConfig,
    duration_s: float,
    engine: IsmConfig,
    raw: RawConfig,
    rng: np.random.Generator,
    chunk_s: float = 1.0,
) -> Iterator[RawChunk]:
    """The raw recording of ``duration_s`` seconds (recording clock) in chunks of ``chunk_s``.

    Parameters and Raises as :func:`simulate_raw`; ``chunk_s`` in [0.01, 60] s. The chunks
    join into exactly the samples of one long run, except that the noise level follows the
    echo power of each chunk (as the clean simulator's does per block).
    """
    n_total = _check_run(config, duration_s, engine, raw, chunk_s)
    c = propagation_speed(config, raw)
    cfg = replace(config, sound_speed_m_s=c)
    stream = _SonarStream(prepare_scene(scene, cfg, engine), trajectory, cfg, engine, raw,
                          _filters(cfg, raw))
    fs, chunk = cfg.fs_hz, max(int(round(chunk_s * raw.fs_hz)), 1)
    cutoff = resample_cutoff_hz(cfg, raw)
    for n0 in range(0, n_total, chunk):
        tau = recording_times(raw, n0, min(chunk, n_total - n0))
        lo = int(math.floor(tau[0] * fs)) - RESAMPLE_HALF_TAPS - 1
        hi = int(math.ceil(tau[-1] * fs)) + RESAMPLE_HALF_TAPS + 1
        stream.drop_before(lo)
        # render at least one period so the noise level is known before the onset too
        stream.extend_to(max(hi, cfg.period_samples - 1))
        x = resample_at(stream.buffer, fs, tau - stream.start / fs, cutoff, RESAMPLE_HALF_TAPS)
        x[tau < 0.0] = 0.0
        power = stream.echo_power(max(lo, 0), max(hi, cfg.period_samples - 1))
        sigma = _noise_sigma(power, cfg, raw)
        if sigma > 0.0:
            x += sigma * rng.standard_normal(x.size)
        clipped = 0
        if raw.full_scale is not None:
            clipped = int(np.count_nonzero(np.abs(x) > raw.full_scale))
            np.clip(x, -raw.full_scale, raw.full_scale, out=x)
        yield RawChunk(start_sample=n0, samples=x, noise_sigma=sigma, clipped_samples=clipped)


def _noise_sigma(echo_power: float, config: SonarConfig, raw: RawConfig) -> float:
    """Noise standard deviation per recording sample: ``echo_power / 10**(snr/10)`` per sonar
    sample, scaled by ``fs_rec / fs`` so the density in the sonar band is the clean run's."""
    if raw.snr_db is None:
        return 0.0
    var = echo_power / 10.0 ** (raw.snr_db / 10.0) * raw.fs_hz / config.fs_hz
    return math.sqrt(var)


def _check_run(config: SonarConfig, duration_s: float, engine: IsmConfig, raw: RawConfig,
               chunk_s: float) -> int:
    """Validate the run's arguments; the number of recording samples."""
    if not isinstance(raw, RawConfig):
        raise ValueError(f"raw must be a RawConfig, got {type(raw).__name__}")
    check_engine(engine)
    if not (isinstance(duration_s, int | float) and 0 < duration_s <= 3600):
        raise ValueError(f"duration_s must be in (0, 3600] s, got {duration_s!r}")
    if not (isinstance(chunk_s, int | float) and 0.01 <= chunk_s <= 60):
        raise ValueError(f"chunk_s must be in [0.01, 60] s, got {chunk_s!r}")
    for band in (raw.speaker_band_hz, raw.mic_band_hz):
        if band is not None:
            band_sos(band, raw.band_order, config.fs_hz)  # raises on a band above fs / 2
    return max(int(round(duration_s * raw.fs_hz)), 1)


def simulate_raw(
    scene: SceneLike,
    trajectory: TrajectoryLike,
    config: SonarConfig,
    duration_s: float,
    engine: IsmConfig,
    raw: RawConfig,
    rng: np.random.Generator,
) -> RawRecording:
    """A raw microphone recording of a robot driving ``trajectory`` through ``scene``.

    Parameters
    ----------
    scene : SceneLike
        Walls and reflection coefficients (2-D; walls infinitely tall).
    trajectory : TrajectoryLike
        Robot path, parameterized by sonar time (the playback clock).
    config : SonarConfig
        The transmitted signal (its ``sound_speed_m_s`` is also the propagation speed unless
        ``raw.temperature_c`` is set).
    duration_s : float
        Length of the recording on the recording clock, in (0, 3600] s.
    engine : IsmConfig
        Image-source settings for the wall echoes; ``spreading`` must be ``3d`` and the
        engine's own noise, tail and odometry noise off (the raw simulator has its own).
    raw : RawConfig
        The effects to add.
    rng : numpy.random.Generator
        Draws the noise (nothing when ``raw.snr_db`` is None).

    Returns
    -------
    RawRecording
        ``round(duration_s * raw.fs_hz)`` samples, the pose log and the ground truth.

    Raises
    ------
    ValueError
        Naming the argument or field that is out of range or not modelled.
    """
    chunks = list(iter_raw_chunks(scene, trajectory, config, duration_s, engine, raw, rng))
    return assemble_raw(chunks, trajectory, config, duration_s, raw)


def assemble_raw(chunks: list[RawChunk], trajectory: TrajectoryLike, config: SonarConfig,
                 duration_s: float, raw: RawConfig) -> RawRecording:
    """Join the chunks of :func:`iter_raw_chunks` (in order) into a :class:`RawRecording` with
    its pose log and ground truth (for callers that show progress while the chunks come)."""
    c = propagation_speed(config, raw)
    delays, gains = static_paths(raw, c)
    rate = raw.fs_hz * (1.0 + raw.clock_offset_ppm * 1e-6)
    truth = RawTruth(
        latency_s=raw.latency_s,
        clock_offset_ppm=raw.clock_offset_ppm,
        sound_speed_m_s=c,
        onset_sample=int(math.ceil(raw.latency_s * rate - 1e-9)),
        direct_delay_s=None if raw.transducer_offset_m is None else raw.transducer_offset_m / c,
        static_delay_s=delays,
        static_gain=gains,
        noise_sigma=np.array([ch.noise_sigma for ch in chunks]),
        clipped_samples=sum(ch.clipped_samples for ch in chunks),
    )
    return RawRecording(
        samples=np.concatenate([ch.samples for ch in chunks]),
        fs_hz=raw.fs_hz,
        poses=pose_log(trajectory, raw, duration_s),
        raw=raw,
        truth=truth,
    )
