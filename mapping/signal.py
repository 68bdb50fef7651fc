"""Sonar configuration and the transmitted signal (paper Sec. 2.1, Table 1).

The loudspeaker plays a BPSK-modulated maximal-length sequence (m-sequence) on a carrier,
repeated without gaps. The configuration fixes the waveform exactly (taps, initial register
state, carrier phase), so a user with real hardware plays the same samples the processing
expects.

Time convention: the transmission has been running since before the run began (steady
state), and sample index ``n`` of the run is emitted at ``t = n / fs``. The transmitted
signal is periodic with one m-sequence period of ``P = L * fs / chip_rate`` samples; between
samples it is the band-limited (periodic sinc) interpolation of the samples, i.e. what an
ideal DAC plays. :func:`transmitted_at` evaluates it at arbitrary times.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import max_len_seq

FloatArray = NDArray[np.float64]

#: Oversampling factor of the table behind :func:`transmitted_at`.
TABLE_UPSAMPLE = 32


def sound_speed_at(temperature_c: float) -> float:
    """Speed of sound in dry air at ``temperature_c`` (deg C): ``331.3 sqrt(1 + T / 273.15)``
    m/s (343.2 m/s at 20 C, 344.4 at 22 C). One home for the simulator of raw recordings
    (the propagation speed) and the importer (the processing's)."""
    if not (math.isfinite(temperature_c) and -60.0 <= temperature_c <= 80.0):
        raise ValueError(f"temperature_c must be in [-60, 80] deg C, got {temperature_c!r}")
    return 331.3 * math.sqrt(1.0 + temperature_c / 273.15)


@dataclass(frozen=True)
class SonarConfig:
    """Parameters of the omnidirectional active sonar (defaults: paper Table 1, M = 10).

    Parameters
    ----------
    sequence_length : int
        m-sequence length L = 2**n - 1.
    carrier_hz : float
        Carrier frequency f_c in Hz.
    chip_rate_hz : float
        Chip rate 1/T_c in Hz.
    fs_hz : float
        Sampling rate f_s in Hz; a whole multiple of the chip rate.
    repetitions : int
        Number M of m-sequence periods per block.
    directions : int
        N: the heat map has rows n_theta = 0..N at angles pi * n_theta / N.
    sound_speed_m_s : float
        Speed of sound c_a in m/s.
    carrier_phase_rad : float
        Carrier phase at sample 0. The default pi/4 keeps every sample non-zero when
        f_c = f_s / 4 (a zero phase would put every other sample at 0).
    mseq_taps : tuple of int or None
        Feedback taps for ``scipy.signal.max_len_seq``; None uses scipy's default for n bits.
    mseq_state : tuple of int or None
        Initial register state (n bits, not all zero); None means all ones.
    """

    sequence_length: int = 1023
    carrier_hz: float = 10_000.0
    chip_rate_hz: float = 10_000.0
    fs_hz: float = 40_000.0
    repetitions: int = 10
    directions: int = 29
    sound_speed_m_s: float = 340.0
    carrier_phase_rad: float = math.pi / 4
    mseq_taps: tuple[int, ...] | None = None
    mseq_state: tuple[int, ...] | None = field(default=None)

    def __post_init__(self) -> None:
        _validate(self)

    # ---- derived values -------------------------------------------------------------
    @property
    def nbits(self) -> int:
        """Register length n of the m-sequence (L = 2**n - 1)."""
        return int(round(math.log2(self.sequence_length + 1)))

    @property
    def samples_per_chip(self) -> int:
        """Samples per chip, fs / chip_rate."""
        return int(round(self.fs_hz / self.chip_rate_hz))

    @property
    def period_samples(self) -> int:
        """Samples per m-sequence period, P = L * fs / chip_rate."""
        return self.sequence_length * self.samples_per_chip

    @property
    def block_samples(self) -> int:
        """Samples per sonar block, B = M * P."""
        return self.repetitions * self.period_samples

    @property
    def period_s(self) -> float:
        """Duration of one m-sequence period in seconds."""
        return self.period_samples / self.fs_hz

    @property
    def block_s(self) -> float:
        """Duration of one sonar block in seconds (1.023 s for Table 1)."""
        return self.block_samples / self.fs_hz

    @property
    def range_per_sample_m(self) -> float:
        """Range per lag sample, c / (2 fs) (4.25 mm for Table 1)."""
        return self.sound_speed_m_s / (2.0 * self.fs_hz)

    @property
    def max_range_m(self) -> float:
        """Unambiguous range of the circular correlation, c * L * T_c / 2 (17.39 m)."""
        return self.period_samples * self.range_per_sample_m

    @property
    def angles_rad(self) -> FloatArray:
        """Direction bank of eq. 1: pi * n_theta / N for n_theta = 0..N."""
        return np.pi * np.arange(self.directions + 1) / self.directions

    # ---- serialization --------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dictionary of the fields."""
        d = asdict(self)
        for key in ("mseq_taps", "mseq_state"):
            if d[key] is not None:
                d[key] = list(d[key])
        return d

    def to_json(self) -> str:
        """JSON text of the fields."""
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SonarConfig:
        """Build from a dictionary; unknown keys raise ``ValueError`` naming them."""
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"SonarConfig: unknown field(s) {unknown}; allowed: {sorted(known)}")
        kwargs = dict(data)
        for key in ("mseq_taps", "mseq_state"):
            if kwargs.get(key) is not None:
                kwargs[key] = tuple(int(v) for v in kwargs[key])
        return cls(**kwargs)

    @classmethod
    def from_json(cls, text: str) -> SonarConfig:
        """Build from JSON text (as written by :meth:`to_json`)."""
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"SonarConfig: not valid JSON ({exc})") from exc
        if not isinstance(data, dict):
            raise ValueError("SonarConfig: JSON must be an object of fields")
        return cls.from_dict(data)


def _validate(cfg: SonarConfig) -> None:
    """Raise ``ValueError`` naming the first invalid field of ``cfg``."""
    for name in ("carrier_hz", "chip_rate_hz", "fs_hz", "sound_speed_m_s"):
        value = getattr(cfg, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise ValueError(f"SonarConfig.{name} must be a positive finite number, got {value!r}")
    for name in ("sequence_length", "repetitions", "directions"):
        value = getattr(cfg, name)
        if not (isinstance(value, int | np.integer) and value >= 1):
            raise ValueError(f"SonarConfig.{name} must be a positive integer, got {value!r}")
    length = cfg.sequence_length
    if length < 3 or (length + 1) & length != 0:
        raise ValueError(
            f"SonarConfig.sequence_length must be 2**n - 1 with n >= 2, got {length}"
        )
    ratio = cfg.fs_hz / cfg.chip_rate_hz
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise ValueError(
            f"SonarConfig.fs_hz ({cfg.fs_hz}) must be a whole multiple of chip_rate_hz "
            f"({cfg.chip_rate_hz})"
        )
    if cfg.carrier_hz >= cfg.fs_hz / 2:
        raise ValueError(
            f"SonarConfig.carrier_hz must be below fs_hz / 2 = {cfg.fs_hz / 2}, "
            f"got {cfg.carrier_hz}"
        )
    cycles = cfg.carrier_hz * length / cfg.chip_rate_hz
    if abs(cycles - round(cycles)) > 1e-6:
        raise ValueError(
            "SonarConfig.carrier_hz must give a whole number of carrier cycles per period "
            f"(carrier_hz * sequence_length / chip_rate_hz = {cycles:g})"
        )
    if not math.isfinite(cfg.carrier_phase_rad):
        raise ValueError(
            f"SonarConfig.carrier_phase_rad must be finite, got {cfg.carrier_phase_rad}"
        )
    nbits = int(round(math.log2(length + 1)))
    if cfg.mseq_state is not None:
        state = cfg.mseq_state
        if len(state) != nbits or any(b not in (0, 1) for b in state) or not any(state):
            raise ValueError(
                f"SonarConfig.mseq_state must be {nbits} bits of 0/1, not all zero, got {state}"
            )
    if cfg.mseq_taps is not None:
        taps = cfg.mseq_taps
        if any((not 0 < t < nbits) for t in taps):
            raise ValueError(f"SonarConfig.mseq_taps must lie in 1..{nbits - 1}, got {taps}")
        seq = _raw_mseq(nbits, taps, cfg.mseq_state)
        if not _is_maximal(seq):
            raise ValueError(f"SonarConfig.mseq_taps {taps} do not give a maximal-length sequence")


def _raw_mseq(
    nbits: int, taps: tuple[int, ...] | None, state: tuple[int, ...] | None
) -> NDArray[np.int8]:
    seq, _ = max_len_seq(
        nbits,
        state=None if state is None else np.asarray(state, dtype=np.int8),
        taps=None if taps is None else np.asarray(taps),
    )
    return np.asarray(seq, dtype=np.int8)


def _is_maximal(seq: NDArray[np.int8]) -> bool:
    """True when the +-1 sequence has the two-valued circular autocorrelation (L, -1)."""
    chips = 1.0 - 2.0 * seq
    acf = np.fft.irfft(np.abs(np.fft.rfft(chips)) ** 2, n=chips.size)
    return bool(np.allclose(acf[1:], -1.0, atol=1e-6))


def mseq_chips(config: SonarConfig) -> FloatArray:
    """The m-sequence of ``config`` as +-1 chips (bit 0 -> +1, bit 1 -> -1), length L."""
    seq = _raw_mseq(config.nbits, config.mseq_taps, config.mseq_state)
    return 1.0 - 2.0 * seq.astype(np.float64)


@lru_cache(maxsize=16)
def _tx_period_cached(config: SonarConfig) -> FloatArray:
    chips = np.repeat(mseq_chips(config), config.samples_per_chip)
    n = np.arange(config.period_samples)
    carrier = np.cos(2 * np.pi * config.carrier_hz * n / config.fs_hz + config.carrier_phase_rad)
    out = chips * carrier
    out.setflags(write=False)
    return out


def tx_period(config: SonarConfig) -> FloatArray:
    """One period (P samples) of the transmitted signal: BPSK chips times the carrier.

    Returns a read-only float64 array; s[n] = chip[n // samples_per_chip] *
    cos(2 pi f_c n / f_s + phase).
    """
    return _tx_period_cached(config)


def tx_samples(config: SonarConfig, start_sample: int, n_samples: int) -> FloatArray:
    """Transmitted samples ``start_sample .. start_sample + n_samples - 1`` of the endless
    transmission (continuous from block to block)."""
    if n_samples < 0:
        raise ValueError(f"n_samples must be >= 0, got {n_samples}")
    period = tx_period(config)
    idx = (start_sample + np.arange(n_samples)) % config.period_samples
    return period[idx]


def tx_block(config: SonarConfig, block_index: int = 0) -> FloatArray:
    """The transmitted block ``block_index`` (M periods, B samples)."""
    return tx_samples(config, block_index * config.block_samples, config.block_samples)


def periodic_table(spectrum: NDArray[np.complexfloating], n_period: int) -> FloatArray:
    """Band-limited periodic interpolant of one period on a grid ``TABLE_UPSAMPLE`` finer.

    ``spectrum`` is the ``rfft`` of a real period of ``n_period`` samples (possibly filtered).
    Exact at the table points (zero-padding of the DFT; the Nyquist bin is split evenly
    between +fs/2 and -fs/2 so the interpolant is real and symmetric). The table carries two
    wrap-around samples before and three after, for :func:`periodic_table_at`; read-only.
    """
    fine = n_period * TABLE_UPSAMPLE
    padded = np.zeros(fine // 2 + 1, dtype=complex)
    padded[: spectrum.size] = spectrum
    if n_period % 2 == 0:
        padded[n_period // 2] *= 0.5
    table = np.fft.irfft(padded, n=fine) * TABLE_UPSAMPLE
    # two wrap-around samples on each side for the cubic stencil
    table = np.concatenate([table[-2:], table, table[:3]])
    table.setflags(write=False)
    return table


def periodic_table_at(table: FloatArray, u: NDArray[np.floating]) -> FloatArray:
    """4-point cubic Lagrange interpolation of a :func:`periodic_table` at fine-grid
    positions ``u`` (table samples, any real value: the table is periodic)."""
    fine = table.size - 5
    u = np.mod(u, fine)
    i = np.floor(u)
    f = u - i
    k = i.astype(np.int64) + 2  # offset of the two leading pad samples
    ym1, y0, y1, y2 = table[k - 1], table[k], table[k + 1], table[k + 2]
    # 4-point Lagrange weights at nodes -1, 0, 1, 2
    wm1 = -f * (f - 1.0) * (f - 2.0) / 6.0
    w0 = (f + 1.0) * (f - 1.0) * (f - 2.0) / 2.0
    w1 = -(f + 1.0) * f * (f - 2.0) / 2.0
    w2 = (f + 1.0) * f * (f - 1.0) / 6.0
    return np.asarray(wm1 * ym1 + w0 * y0 + w1 * y1 + w2 * y2)


@lru_cache(maxsize=16)
def _tx_table(config: SonarConfig) -> FloatArray:
    """:func:`periodic_table` of the transmitted period."""
    period = tx_period(config)
    return periodic_table(np.fft.rfft(period), period.size)


def transmitted_at(t_s: NDArray[np.floating] | float, config: SonarConfig) -> FloatArray:
    """Transmitted signal at arbitrary times ``t_s`` (seconds), band-limited.

    Evaluates the periodic band-limited interpolant of the samples (sample n at n / fs) by
    4-point cubic Lagrange interpolation on a table oversampled 32x; relative error about
    1e-6 against the exact trigonometric interpolant (tested).

    Parameters
    ----------
    t_s : array_like
        Times in seconds, any shape.
    config : SonarConfig

    Returns
    -------
    numpy.ndarray
        Signal values, same shape as ``t_s``.
    """
    u = np.asarray(t_s, dtype=np.float64) * (config.fs_hz * TABLE_UPSAMPLE)
    return periodic_table_at(_tx_table(config), u)


def transmitted_exact(t_s: NDArray[np.floating], config: SonarConfig) -> FloatArray:
    """Exact trigonometric (periodic band-limited) interpolant at ``t_s``; O(P) per point.

    The slow, obviously correct twin of :func:`transmitted_at`, for tests.
    """
    period = tx_period(config)
    p = period.size
    spec = np.fft.rfft(period) / p
    k = np.arange(spec.size)
    weights = np.full(spec.size, 2.0)
    weights[0] = 1.0
    if p % 2 == 0:
        weights[-1] = 1.0
    t = np.atleast_1d(np.asarray(t_s, dtype=np.float64)).ravel()
    out = np.empty(t.shape)
    for a in range(0, t.size, 256):  # 256 points x P / 2 phases at a time
        phase = np.exp(2j * np.pi * np.outer(np.mod(t[a:a + 256] * config.fs_hz, p), k) / p)
        out[a:a + 256] = (phase * (weights * spec)).real.sum(axis=1)
    return out.reshape(np.shape(t_s)) if np.ndim(t_s) else out


def checked_speed_m_s(speed_m_s: float, config: SonarConfig) -> float:
    """``speed_m_s`` as a float, or ``ValueError`` naming it unless finite and below c/10.

    Eq. 1 and everything that predicts it (the forward model) assume ``|v| << c``; c/10 is
    the bound both enforce.
    """
    if not isinstance(config, SonarConfig):
        raise ValueError(f"config must be a SonarConfig, got {type(config).__name__}")
    try:
        v = float(speed_m_s)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"speed_m_s must be a real number, got {speed_m_s!r}") from exc
    c = config.sound_speed_m_s
    if not math.isfinite(v) or abs(v) >= c / 10.0:
        raise ValueError(f"speed_m_s must be finite with |speed_m_s| < c/10 = {c / 10:g}, got {v}")
    return v


def playback_signal(config: SonarConfig, fs_hz: float, n_samples: int) -> FloatArray:
    """What the loudspeaker must play at a sound-card rate: the transmitted signal at sonar
    times ``n / fs_hz`` for n = 0 .. n_samples - 1 (the playback clock is the sonar clock).

    Parameters
    ----------
    config : SonarConfig
    fs_hz : float
        Playback rate in Hz, at least ``config.fs_hz`` (the signal fills 0 .. fs / 2).
    n_samples : int
        Number of samples, >= 0; play them once, not looped (a period is rarely a whole
        number of playback samples).

    Returns
    -------
    numpy.ndarray
        float64 samples, peak about 1.4 (the band-limited BPSK overshoots its +-1 samples).
    """
    if not (isinstance(fs_hz, int | float) and math.isfinite(fs_hz) and fs_hz >= config.fs_hz):
        raise ValueError(f"fs_hz must be a finite rate >= config.fs_hz = {config.fs_hz:g}, "
                         f"got {fs_hz!r}")
    if not (isinstance(n_samples, int | np.integer) and n_samples >= 0):
        raise ValueError(f"n_samples must be an integer >= 0, got {n_samples!r}")
    return transmitted_at(np.arange(n_samples) / float(fs_hz), config)
