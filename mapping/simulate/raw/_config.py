"""Parameters of the raw-recording simulator: :class:`RawConfig` and the speed of sound.

Every effect is optional and off by default, so the default configuration records the clean
image-source stream at 48 kHz with no latency, no clock offset, no direct wave, no floor or
ceiling, flat transducers, the sonar's own speed of sound and no noise.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

#: Allowed sound-card rates in Hz (inclusive).
FS_RANGE_HZ = (40_000.0, 192_000.0)


@dataclass(frozen=True)
class RawConfig:
    """What a real sound card, room and pair of transducers add to the clean echoes.

    Parameters
    ----------
    fs_hz : float
        Sound-card (recording) rate in Hz, in [40 000, 192 000].
    latency_s : float
        Time from the first recorded sample to the start of playback, in [0, 2] s.
    clock_offset_ppm : float
        Recording clock rate error in ppm, |.| <= 1000; positive: the recording clock runs
        fast (more samples per true second).
    transducer_offset_m : float or None
        Distance between loudspeaker and microphone in m, in (0, 0.5]; None: no direct wave
        (and pure vertical bounces straight up and down).
    sonar_height_m : float or None
        Height of the sonar above the floor in m (> 0); None: no floor and no ceiling.
    ceiling_height_m : float or None
        Height of the ceiling in m, above ``sonar_height_m``; None: no ceiling.
    floor_reflection, ceiling_reflection : float
        Pressure reflection coefficients of floor and ceiling, in [0, 1].
    vertical_order : int
        1: the floor/ceiling images alone (constant delay, no Doppler); 2: also each wall
        path combined with each floor/ceiling image (3-D delay, the wall path's Doppler).
    vertical_bounces : int
        Most floor/ceiling reflections on one path, 1..6.
    speaker_band_hz, mic_band_hz : (float, float) or None
        Pass bands (lo, hi) in Hz of the loudspeaker and the microphone, each a causal
        Butterworth band-pass of order ``band_order`` at the sonar rate, ``0 < lo < hi <
        fs / 2`` of the sonar; None: flat.
    band_order : int
        Butterworth order of each band-pass edge, 1..8.
    temperature_c : float or None
        Air temperature in deg C, in [-40, 60]: sound travels at
        :func:`mapping.signal.sound_speed_at` instead of the ``SonarConfig``'s
        ``sound_speed_m_s``; None: the config's speed.
    snr_db : float or None
        White noise at this SNR against the wall-echo power (direct wave and floor/ceiling
        excluded), per sample at the sonar rate (so its density in the sonar band matches a
        clean run's at the same SNR); None: no noise.
    full_scale : float or None
        Clip the recorded samples to +-full_scale (> 0), as a sound card does; None: no clip.
    pose_step_s : float
        Spacing of the pose-log rows on the recording clock, in [0.001, 1] s.
    body_echoes : tuple of (float, float)
        Echoes off the robot's own body (a bumper, a mast): each ``(path_m, reflection)``,
        the loudspeaker-body-microphone path in (0, 2] m and a reflection in [0, 1], heard
        with 3-D spreading ``reflection / path``; they ride with the robot (constant delay,
        no Doppler) like the direct wave.
    """

    fs_hz: float = 48_000.0
    latency_s: float = 0.0
    clock_offset_ppm: float = 0.0
    transducer_offset_m: float | None = None
    sonar_height_m: float | None = None
    ceiling_height_m: float | None = None
    floor_reflection: float = 0.9
    ceiling_reflection: float = 0.7
    vertical_order: int = 1
    vertical_bounces: int = 2
    speaker_band_hz: tuple[float, float] | None = None
    mic_band_hz: tuple[float, float] | None = None
    band_order: int = 2
    temperature_c: float | None = None
    snr_db: float | None = None
    full_scale: float | None = None
    pose_step_s: float = 0.05
    body_echoes: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        _check_range("fs_hz", self.fs_hz, *FS_RANGE_HZ)
        _check_range("latency_s", self.latency_s, 0.0, 2.0)
        _check_range("clock_offset_ppm", self.clock_offset_ppm, -1000.0, 1000.0)
        if self.transducer_offset_m is not None:
            _check_range("transducer_offset_m", self.transducer_offset_m, 1e-4, 0.5)
        if self.sonar_height_m is not None:
            _check_range("sonar_height_m", self.sonar_height_m, 1e-3, 100.0)
        if self.ceiling_height_m is not None:
            if self.sonar_height_m is None:
                raise ValueError("RawConfig.ceiling_height_m needs sonar_height_m (got None)")
            _check_range("ceiling_height_m", self.ceiling_height_m,
                         self.sonar_height_m + 1e-3, 100.0)
        _check_range("floor_reflection", self.floor_reflection, 0.0, 1.0)
        _check_range("ceiling_reflection", self.ceiling_reflection, 0.0, 1.0)
        _check_int("vertical_order", self.vertical_order, 1, 2)
        _check_int("vertical_bounces", self.vertical_bounces, 1, 6)
        _check_int("band_order", self.band_order, 1, 8)
        for name in ("speaker_band_hz", "mic_band_hz"):
            band = getattr(self, name)
            if band is not None and not (
                len(band) == 2 and all(_is_real(v) for v in band) and 0 < band[0] < band[1]
            ):
                raise ValueError(
                    f"RawConfig.{name} must be None or (lo, hi) with 0 < lo < hi Hz, got {band!r}"
                )
        if self.temperature_c is not None:
            _check_range("temperature_c", self.temperature_c, -40.0, 60.0)
        if self.snr_db is not None:
            _check_range("snr_db", self.snr_db, -60.0, 200.0)
        if self.full_scale is not None:
            _check_range("full_scale", self.full_scale, 1e-12, 1e12)
        _check_range("pose_step_s", self.pose_step_s, 1e-3, 1.0)
        for i, echo in enumerate(self.body_echoes):
            if not (len(echo) == 2 and all(_is_real(v) for v in echo)
                    and 0 < echo[0] <= 2.0 and 0 <= echo[1] <= 1.0):
                raise ValueError(f"RawConfig.body_echoes[{i}] must be (path_m in (0, 2], "
                                 f"reflection in [0, 1]), got {echo!r}")

    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary of the fields (for metadata)."""
        return asdict(self)


def _is_real(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _check_range(name: str, value: object, lo: float, hi: float) -> None:
    """``ValueError`` naming ``RawConfig.name`` unless ``value`` is a real number in [lo, hi]."""
    if not (_is_real(value) and lo <= value <= hi):  # type: ignore[operator]
        raise ValueError(f"RawConfig.{name} must be a number in [{lo:g}, {hi:g}], got {value!r}")


def _check_int(name: str, value: object, lo: int, hi: int) -> None:
    """``ValueError`` naming ``RawConfig.name`` unless ``value`` is an integer in lo..hi."""
    if not (isinstance(value, int) and not isinstance(value, bool) and lo <= value <= hi):
        raise ValueError(f"RawConfig.{name} must be an integer in {lo}..{hi}, got {value!r}")
