"""``omnisonar import-run --raw`` and ``omnisonar signal --rate``: output, JSON, refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.io import wavfile

from mapping.files import read_run, read_wav_raw, write_pose_csv
from mapping.recording import PoseLog
from mapping.signal import SonarConfig, playback_signal
from service.cli import main
from tests.mapping.recording.synth import RawScene, raw_stream, wall_echo

CFG = SonarConfig()
SCENE = RawScene(fs_rec_hz=48_000.0, latency_s=0.0623, clock_offset_ppm=31.0, duration_s=3.5,
                 echoes=(wall_echo(1.2, 0.1), wall_echo(0.1, gain=0.01)))


def _pcm16(path: Path, x: np.ndarray, fs: float) -> Path:
    wavfile.write(path, int(fs), np.round(np.clip(x, -1, 32767 / 32768) * 32768).astype(np.int16))
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("raw")
    x = raw_stream(SCENE, CFG, np.random.default_rng(2)) + 0.0  # peak ~0.3: no clipping
    t = np.linspace(0.0, 4.0, 41)
    log = PoseLog(t_s=t, x_m=0.1 * t, y_m=np.zeros(t.size), heading_rad=np.zeros(t.size),
                  speed_m_s=np.full(t.size, 0.1))
    return {
        "wav": _pcm16(d / "raw.wav", x, SCENE.fs_rec_hz),
        "clipped": _pcm16(d / "clipped.wav", 5.0 * x, SCENE.fs_rec_hz),
        "slow": _pcm16(d / "slow.wav", x[: 30_000], 32_000.0),
        "poses": write_pose_csv(d / "poses.csv", log),
        "dir": d,
    }


def test_json_report_and_run_file(files: dict[str, Path],
                                  capsys: pytest.CaptureFixture[str]) -> None:
    out = files["dir"] / "run.npz"
    assert main(["import-run", "--raw", "--wav", str(files["wav"]), "--poses",
                 str(files["poses"]), "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert abs(report["latency_s"] - SCENE.latency_s) * SCENE.fs_rec_hz < 0.05
    assert abs(report["clock_offset_ppm"] - SCENE.clock_offset_ppm) < 2.0
    assert report["method"] == "gated" and report["direct_suppression_db"] >= 40.0  # default
    run = read_run(out)
    assert run.n_blocks == report["blocks"] == report["blocks_written"] == 3
    assert run.meta["raw_import"]["latency_s"] == report["latency_s"]
    assert run.meta["wav"] == "raw.wav"


def test_text_report(files: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["import-run", "--raw", "--wav", str(files["wav"]), "--poses",
                 str(files["poses"]), "--out", str(files["dir"] / "g.npz"), "--static", "gated",
                 "--offset", "0.05", "--blocks", "1"]) == 0
    text = capsys.readouterr().out
    assert "latency          62.3" in text and "clock offset     +31.0" in text
    assert "static removal   gated" in text and "wrote" in text and "1 blocks" in text
    assert "warning: gated removal without --sonar-height" in text


@pytest.mark.parametrize(("extra", "fragment"), [
    (["--static", "calibration"], "--static calibration needs --calibration"),
    (["--ceiling-height", "2.5"], "ceiling_height_m needs sonar_height_m"),
    (["--temperature", "99"], "temperature_c must lie in"),
])
def test_refusals_of_options(files: dict[str, Path], capsys: pytest.CaptureFixture[str],
                             extra: list[str], fragment: str) -> None:
    assert main(["import-run", "--raw", "--wav", str(files["wav"]), "--poses",
                 str(files["poses"]), "--out", str(files["dir"] / "x.npz"), *extra]) == 2
    assert fragment in capsys.readouterr().err


@pytest.mark.parametrize(("key", "fragment"), [
    ("clipped", "clipping: "),
    ("slow", "unsupported sample rate 32000 Hz"),
])
def test_refusals_of_recordings(files: dict[str, Path], capsys: pytest.CaptureFixture[str],
                                key: str, fragment: str) -> None:
    assert main(["import-run", "--raw", "--wav", str(files[key]), "--poses",
                 str(files["poses"]), "--out", str(files["dir"] / "x.npz")]) == 2
    err = capsys.readouterr().err
    assert fragment in err and files[key].name in err
    assert not (files["dir"] / "x.npz").exists()


def test_raw_options_need_raw(files: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["import-run", "--wav", str(files["wav"]), "--poses", str(files["poses"]),
                 "--out", str(files["dir"] / "x.npz"), "--json", "--static", "run"]) == 2
    assert "--static, --json only apply to raw recordings: add --raw" in capsys.readouterr().err


def test_help_shows_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["import-run", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: 0.05)" in text and "--calibration CAL.wav" in text


def test_signal_at_a_sound_card_rate(tmp_path: Path) -> None:
    out = tmp_path / "play.wav"
    assert main(["signal", "--out", str(out), "--rate", "48000", "--seconds", "0.5"]) == 0
    wav = read_wav_raw(out)
    assert wav.fs_hz == 48_000.0 and wav.samples.size == 24_000
    expected = playback_signal(CFG, 48_000.0, 24_000)
    np.testing.assert_allclose(wav.samples, 0.5 * expected / np.abs(expected).max(), atol=1e-6)
