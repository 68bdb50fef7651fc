"""``omnisonar simulate --raw-wav/--raw-poses``: files equal to :func:`simulate_raw`'s
recording with the options' configuration; clear errors for incomplete options."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mapping.files import read_pose_csv, read_wav_raw
from mapping.path import builtin_path
from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from mapping.simulate.ism import IsmConfig
from mapping.simulate.raw import RawConfig, simulate_raw


def test_raw_all_writes_the_simulators_recording(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    from service.cli import main

    wav, poses = tmp_path / "rec.wav", tmp_path / "poses.csv"
    rc = main(["simulate", "--scene", "builtin:paper", "--path", "paper-b", "--blocks", "1",
               "--raw-wav", str(wav), "--raw-poses", str(poses), "--raw-all",
               "--snr-db", "10", "--seed", "3"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "latency 37.000 ms" in out and "+60 ppm" in out and "344.38 m/s" in out
    raw = RawConfig(fs_hz=48_000.0, latency_s=0.037, clock_offset_ppm=60.0,
                    transducer_offset_m=0.05, sonar_height_m=0.3, ceiling_height_m=2.6,
                    vertical_order=2, speaker_band_hz=(1_500.0, 18_000.0),
                    mic_band_hz=(50.0, 19_000.0), temperature_c=22.0, snr_db=10.0,
                    body_echoes=((0.3, 0.3),))
    config = SonarConfig()
    duration = (config.block_s + 0.037) * (1 + 60e-6)
    want = simulate_raw(builtin_scene("paper"), builtin_path("paper-b"), config, duration,
                        IsmConfig(), raw, np.random.default_rng(3))
    got = read_wav_raw(wav)
    assert got.fs_hz == 48_000.0 and got.samples.size == want.samples.size
    assert np.allclose(got.samples, want.samples.astype(np.float32), rtol=1e-6, atol=1e-6)
    log = read_pose_csv(poses)
    assert np.allclose(log.t_s, want.poses.t_s) and np.allclose(log.x_m, want.poses.x_m)
    assert log.t_s[-1] >= duration


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--raw-wav", "a.wav"], "--raw-wav and --raw-poses go together"),
        ([], "give --out RUN.npz, or --raw-wav and --raw-poses"),
        (["--raw-wav", "a.wav", "--raw-poses", "p.csv", "--rate", "8000"], "RawConfig.fs_hz"),
    ],
)
def test_raw_options_errors(extra: list[str], message: str, tmp_path: Path,
                            capsys: pytest.CaptureFixture[str],
                            monkeypatch: pytest.MonkeyPatch) -> None:
    from service.cli import main

    monkeypatch.chdir(tmp_path)
    rc = main(["simulate", "--scene", "builtin:paper", "--path", "paper-b", "--blocks", "1",
               *extra])
    assert rc == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "a.wav").exists()
