"""RawConfig validation and the speed of sound."""

from __future__ import annotations

from typing import Any

import pytest

from mapping.signal import sound_speed_at
from mapping.simulate.raw import RawConfig


def test_sound_speed_of_air() -> None:
    """331.3 m/s at 0 C; 343.2 m/s at 20 C (textbook value 343.2)."""
    assert sound_speed_at(0.0) == pytest.approx(331.3)
    assert sound_speed_at(20.0) == pytest.approx(343.2, abs=0.05)


def test_defaults_switch_every_effect_off() -> None:
    raw = RawConfig()
    assert raw.latency_s == 0 and raw.clock_offset_ppm == 0
    assert raw.transducer_offset_m is None and raw.sonar_height_m is None
    assert raw.speaker_band_hz is None and raw.mic_band_hz is None
    assert raw.temperature_c is None and raw.snr_db is None and raw.full_scale is None


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("fs_hz", 8000.0, "fs_hz must be a number in \\[40000, 192000\\]"),
        ("fs_hz", float("nan"), "fs_hz"),
        ("latency_s", -0.001, "latency_s"),
        ("clock_offset_ppm", 1500.0, "clock_offset_ppm"),
        ("transducer_offset_m", 0.0, "transducer_offset_m"),
        ("transducer_offset_m", 2.0, "transducer_offset_m"),
        ("sonar_height_m", -1.0, "sonar_height_m"),
        ("floor_reflection", 1.5, "floor_reflection"),
        ("vertical_order", 3, "vertical_order must be an integer in 1..2"),
        ("vertical_bounces", 0, "vertical_bounces"),
        ("band_order", 2.0, "band_order"),
        ("speaker_band_hz", (18_000.0, 1_500.0), "speaker_band_hz"),
        ("mic_band_hz", (0.0, 19_000.0), "mic_band_hz"),
        ("temperature_c", 100.0, "temperature_c"),
        ("snr_db", float("inf"), "snr_db"),
        ("full_scale", 0.0, "full_scale"),
        ("pose_step_s", 0.0, "pose_step_s"),
    ],
)
def test_bad_fields_name_themselves(field: str, value: Any, message: str) -> None:
    with pytest.raises(ValueError, match=f"RawConfig.{message}"):
        RawConfig(**{field: value})


def test_ceiling_needs_a_sonar_height_below_it() -> None:
    with pytest.raises(ValueError, match="ceiling_height_m needs sonar_height_m"):
        RawConfig(ceiling_height_m=2.5)
    with pytest.raises(ValueError, match="ceiling_height_m"):
        RawConfig(sonar_height_m=3.0, ceiling_height_m=2.5)
