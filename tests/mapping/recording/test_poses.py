"""Real recordings: blocks from a stream, pose interpolation, file errors, CLI round trip."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping.files import (
    read_pose_csv,
    read_run,
    read_wav_mono,
    write_pose_csv,
    write_run,
    write_wav,
)
from mapping.recording import (
    PoseLog,
    block_odometry,
    join_blocks,
    pose_log_from_blocks,
    poses_at,
    split_blocks,
)
from mapping.run import Run
from mapping.signal import SonarConfig
from service.cli import main
from service.commands.runs import resolve_scene

CFG = SonarConfig(sequence_length=127, repetitions=2)  # small blocks: B = 1016


def _log(t: np.ndarray, heading: np.ndarray, speed: np.ndarray | None = None) -> PoseLog:
    return PoseLog(t_s=t, x_m=0.1 * t, y_m=-0.05 * t, heading_rad=heading,
                   speed_m_s=np.full(t.size, 0.1) if speed is None else speed)


def test_split_blocks_alignment_and_partial_tail() -> None:
    x = np.arange(3 * 10 + 7, dtype=np.float64)
    blocks = split_blocks(x, 10)
    assert blocks.shape == (3, 10) and blocks.dtype == np.float32
    for k in range(3):  # block k = samples kB .. (k+1)B - 1
        np.testing.assert_array_equal(blocks[k], np.arange(10 * k, 10 * k + 10))
    np.testing.assert_array_equal(join_blocks(blocks), x[:30])
    with pytest.raises(ValueError, match="fewer than one block"):
        split_blocks(x[:9], 10)
    with pytest.raises(ValueError, match="mono"):
        split_blocks(np.zeros((40, 2)), 10)


def test_heading_interpolates_along_the_short_arc() -> None:
    # from +170 deg to -170 deg the short way passes through 180 deg, not 0
    t = np.array([0.0, 1.0])
    log = _log(t, np.radians([170.0, -170.0]))
    h = poses_at(log, np.array([0.5, 0.25]))[:, 2]
    np.testing.assert_allclose(np.abs(h), [math.pi, math.radians(175)], atol=1e-12)
    assert h[1] > 0  # 175 deg, not -175
    with pytest.raises(ValueError, match="outside the pose log"):
        poses_at(log, np.array([1.5]))


def test_block_odometry_against_analytic_motion() -> None:
    """A robot turning at constant yaw rate with linearly growing speed, logged every 0.1 s."""
    block_s = 1.0
    t = np.arange(0.0, 5.0001, 0.1)
    yaw, v0, acc = 0.7, 0.05, 0.01
    log = PoseLog(t_s=t, x_m=np.cos(t), y_m=np.sin(t), heading_rad=yaw * t,
                  speed_m_s=v0 + acc * t)
    odo = block_odometry(log, 5, block_s)
    mid = np.arange(5) + 0.5
    np.testing.assert_array_equal(odo.t_s, np.arange(5.0))
    # speed linear in t: the block mean is the value at the midpoint, exactly
    np.testing.assert_allclose(odo.speed_m_s, v0 + acc * mid, rtol=1e-12)
    np.testing.assert_allclose(odo.yaw_rate_rad_s, yaw, rtol=1e-12)
    wrapped = np.angle(np.exp(1j * yaw * mid))
    np.testing.assert_allclose(odo.pose[:, 2], wrapped, atol=1e-12)
    # x, y linear between rows 0.1 s apart: chord error of the unit circle <= 0.1^2/8
    np.testing.assert_allclose(odo.pose[:, 0], np.cos(mid), atol=0.0013)
    np.testing.assert_allclose(odo.pose[:, 1], np.sin(mid), atol=0.0013)
    with pytest.raises(ValueError, match="outside the pose log"):
        block_odometry(log, 6, block_s)


def test_block_odometry_with_a_log_starting_late() -> None:
    # the log starts at 0.2 s: block 0's mean speed is taken over [0.2, 1.0]
    t = np.array([0.2, 0.6, 1.0, 2.0])
    log = _log(t, np.zeros(4), speed=np.array([0.2, 0.2, 0.0, 0.0]))
    odo = block_odometry(log, 1, 1.0)
    expected = (0.2 * 0.4 + 0.5 * 0.2 * 0.4) / 0.8
    assert odo.speed_m_s[0] == pytest.approx(expected, rel=1e-12)


def test_pose_log_validation_names_column_and_row() -> None:
    t = np.array([0.0, 1.0, 1.0])
    with pytest.raises(ValueError, match=r"t_s must increase strictly; row 2"):
        _log(t, np.zeros(3))
    with pytest.raises(ValueError, match=r"heading_rad must be finite; row 1"):
        _log(np.arange(3.0), np.array([0.0, np.nan, 0.0]))


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 8), st.floats(-3.0, 3.0), st.floats(0.0, 0.5))
def test_property_export_import_reproduces_poses(n: int, yaw_rate: float, speed: float) -> None:
    """Block-midpoint rows written out and read back give the same poses (pure functions)."""
    block_s = 1.0
    n = n + 1
    t0 = np.arange(n) * block_s
    heading = np.angle(np.exp(1j * (0.3 + yaw_rate * (t0 + 0.5))))
    pose = np.column_stack([np.cos(t0), t0 ** 2, heading])
    log = pose_log_from_blocks(t0, pose, np.full(n, speed), block_s)
    odo = block_odometry(log, n, block_s)
    np.testing.assert_allclose(odo.pose[:, :2], pose[:, :2], atol=1e-12)
    np.testing.assert_allclose(np.angle(np.exp(1j * (odo.pose[:, 2] - heading))), 0.0,
                               atol=1e-9)
    np.testing.assert_allclose(odo.speed_m_s, speed, atol=1e-12)
    if abs(yaw_rate) * block_s < math.pi:  # the heading log can be unwrapped unambiguously
        np.testing.assert_allclose(odo.yaw_rate_rad_s, yaw_rate, atol=1e-9)


# ---- files ------------------------------------------------------------------------------
def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("", "empty file"),
        ("t_s,x_m,y_m,heading_rad\n0,0,0,0\n", "missing column(s) ['speed_m_s']"),
        ("t_s,x_m,y_m,heading_rad,speed_m_s\n0,0,0,0,0.1\n1,abc,0,0,0.1\n",
         "line 3: column 'x_m': cannot read 'abc'"),
        ("t_s,x_m,y_m,heading_rad,speed_m_s\n0,0,0,0,0.1\n1,0,0,nan,0.1\n",
         "line 3: column 'heading_rad'"),
        ("t_s,x_m,y_m,heading_rad,speed_m_s\n0,0,0,0,0.1\n0,0,0,0,0.1\n",
         "line 3: column 't_s'"),
        ("t_s,x_m,y_m,heading_rad,speed_m_s\n0,0,0,0,0.1\n", "needs >= 2 pose rows"),
        ("t_s,x_m,y_m,heading_rad,speed_m_s\n0,0,0,0,0.1\n1,0,0,0\n", "column 'speed_m_s'"),
    ],
)
def test_bad_csv_errors(tmp_path: Path, text: str, fragment: str) -> None:
    path = _write(tmp_path / "poses.csv", text)
    with pytest.raises(ValueError) as info:
        read_pose_csv(path)
    assert "poses.csv" in str(info.value)
    assert fragment in str(info.value)


def test_csv_extra_columns_and_order(tmp_path: Path) -> None:
    path = _write(tmp_path / "p.csv", "speed_m_s,note,t_s,x_m,y_m,heading_rad\n"
                  "0.1,a,0,1,2,3\n0.2,b,1,4,5,6\n")
    log = read_pose_csv(path)
    np.testing.assert_array_equal(log.x_m, [1, 4])
    np.testing.assert_array_equal(log.speed_m_s, [0.1, 0.2])


def test_csv_round_trip_is_exact(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.01, 1, 20))
    log = PoseLog(t_s=t, x_m=rng.normal(size=20), y_m=rng.normal(size=20),
                  heading_rad=rng.uniform(-3, 3, 20), speed_m_s=rng.normal(size=20))
    again = read_pose_csv(write_pose_csv(tmp_path / "p.csv", log))
    for name in ("t_s", "x_m", "y_m", "heading_rad", "speed_m_s"):
        np.testing.assert_array_equal(getattr(again, name), getattr(log, name))


def test_wav_checks(tmp_path: Path) -> None:
    from scipy.io import wavfile

    wavfile.write(tmp_path / "st.wav", 40000, np.zeros((100, 2), dtype=np.int16))
    with pytest.raises(ValueError, match="mono"):
        read_wav_mono(tmp_path / "st.wav", 40000)
    wavfile.write(tmp_path / "r.wav", 44100, np.zeros(100, dtype=np.int16))
    with pytest.raises(ValueError, match="44100"):
        read_wav_mono(tmp_path / "r.wav", 40000)
    _write(tmp_path / "junk.wav", "not a wav")
    with pytest.raises(ValueError, match="junk.wav"):
        read_wav_mono(tmp_path / "junk.wav", 40000)
    wavfile.write(tmp_path / "i16.wav", 40000, np.array([-32768, 0, 16384], dtype=np.int16))
    np.testing.assert_array_equal(read_wav_mono(tmp_path / "i16.wav", 40000), [-1, 0, 0.5])
    x = np.array([0.25, -0.5], dtype=np.float32)
    np.testing.assert_array_equal(read_wav_mono(write_wav(tmp_path / "f.wav", x, 40000), 40000), x)


# ---- CLI ----------------------------------------------------------------------------------
def _config_file(tmp_path: Path) -> Path:
    return _write(tmp_path / "cfg.json", CFG.to_json())


def _run(n: int) -> Run:
    rng = np.random.default_rng(7)
    t0 = np.asarray(np.arange(n) * CFG.block_s, dtype=np.float64)
    mid = t0 + 0.5 * CFG.block_s
    heading = np.angle(np.exp(1j * (3.0 + 0.4 * mid)))  # wraps past pi during the run
    return Run(
        config=CFG, samples=rng.normal(size=(n, CFG.block_samples)).astype(np.float32),
        t_s=t0, speed_m_s=np.full(n, 0.1), yaw_rate_rad_s=np.full(n, 0.4),
        pose=np.column_stack([1 + 0.1 * mid, 2 - 0.03 * mid, heading]),
    )


def test_cli_export_import_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = _run(6)
    write_run(tmp_path / "a.npz", run)
    assert main(["export-run", str(tmp_path / "a.npz"), "--wav", str(tmp_path / "a.wav"),
                 "--poses", str(tmp_path / "a.csv")]) == 0
    assert main(["import-run", "--wav", str(tmp_path / "a.wav"), "--poses",
                 str(tmp_path / "a.csv"), "--out", str(tmp_path / "b.npz"),
                 "--config", str(_config_file(tmp_path))]) == 0
    back = read_run(tmp_path / "b.npz")
    np.testing.assert_array_equal(back.samples, run.samples)
    np.testing.assert_array_equal(back.t_s, run.t_s)
    np.testing.assert_allclose(back.pose, run.pose, atol=1e-12)
    np.testing.assert_allclose(back.speed_m_s, run.speed_m_s, rtol=1e-12)
    np.testing.assert_allclose(back.yaw_rate_rad_s, run.yaw_rate_rad_s, rtol=1e-9)
    assert back.meta["source"] == "import-run"
    assert "6 blocks" in capsys.readouterr().out


def test_cli_import_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = _run(4)
    write_run(tmp_path / "a.npz", run)
    main(["export-run", str(tmp_path / "a.npz"), "--wav", str(tmp_path / "a.wav"),
          "--poses", str(tmp_path / "a.csv")])
    cfg = str(_config_file(tmp_path))
    capsys.readouterr()
    # default config (paper rate 40 kHz, B = 40920) > the 4064-sample WAV
    assert main(["import-run", "--wav", str(tmp_path / "a.wav"), "--poses",
                 str(tmp_path / "a.csv"), "--out", str(tmp_path / "b.npz")]) == 2
    assert "a.wav" in capsys.readouterr().err
    # a pose log covering only the first two block midpoints
    lines = (tmp_path / "a.csv").read_text().splitlines()
    _write(tmp_path / "short.csv", "\n".join(lines[:3]) + "\n")
    args = ["import-run", "--wav", str(tmp_path / "a.wav"), "--poses", str(tmp_path / "short.csv"),
            "--out", str(tmp_path / "b.npz"), "--config", cfg]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "short.csv" in err and "--blocks" in err
    assert main([*args, "--blocks", "2"]) == 0
    assert read_run(tmp_path / "b.npz").n_blocks == 2


def test_cli_scenes_and_resolve_scene(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    for name in ("paper", "shoebox", "l-room", "corridor", "pillar", "paper-a", "paper-b",
                 "pillar-curve"):
        assert name in out
    assert main(["scenes", "--show", "shoebox"]) == 0
    (tmp_path / "s.json").write_text(capsys.readouterr().out)
    assert resolve_scene(str(tmp_path / "s.json")) == resolve_scene("builtin:shoebox")
    (tmp_path / "bad.json").write_text('{"name": "b", "walls": [{"start": [0, 0], "end": [0, 0],'
                                       ' "name": "w0"}]}')
    with pytest.raises(ValueError, match=r"bad\.json.*walls\[0\] \('w0'\)"):
        resolve_scene(str(tmp_path / "bad.json"))
    with pytest.raises(FileNotFoundError):
        resolve_scene(str(tmp_path / "none.json"))
    with pytest.raises(ValueError, match="scene name"):
        resolve_scene("builtin:nope")
