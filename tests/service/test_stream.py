"""``omnisonar stream``: a simulated raw recording streamed to the service (TestClient), from a
WAV and from stdin PCM; refusals."""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from mapping.files import write_map, write_pose_csv, write_wav
from mapping.path import builtin_path
from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from mapping.simulate.ism import IsmConfig
from mapping.simulate.raw import RawConfig, RawRecording, simulate_raw
from mapping.wallmap import wallmap_from_walls
from service.app import create_app
from service.cli import build_parser
from service.commands.stream import _cmd_stream
from service.settings import Settings, get_settings

RAW = RawConfig(fs_hz=48_000.0, latency_s=0.037, clock_offset_ppm=60.0,
                transducer_offset_m=0.05, sonar_height_m=0.3, ceiling_height_m=2.6,
                temperature_c=22.0, snr_db=10.0)


@cache
def recording() -> RawRecording:
    return simulate_raw(builtin_scene("shoebox"), builtin_path("shoebox-straight"),
                        SonarConfig(), 8.5, IsmConfig(max_order=2, max_path_m=12.0), RAW,
                        np.random.default_rng(2))


@pytest.fixture()
def files(tmp_path: Path) -> tuple[Path, Path]:
    rec = recording()
    wav, poses = tmp_path / "rec.wav", tmp_path / "poses.csv"
    write_wav(wav, rec.samples / np.abs(rec.samples).max() * 0.5, rec.fs_hz)
    write_pose_csv(poses, rec.poses)
    return wav, poses


@pytest.fixture()
def client(tmp_path: Path) -> Iterator[TestClient]:
    scene = builtin_scene("shoebox")
    maps = tmp_path / "maps"
    maps.mkdir()
    write_map(maps / "room.npz", wallmap_from_walls(scene.segments().reshape(-1, 4),
                                                    np.abs(scene.reflection_coefficients())))
    settings = Settings(maps_dir=maps, sessions_dir=tmp_path / "sessions",
                        runs_dir=tmp_path / "runs", default_map=False)
    app = create_app()
    app.dependency_overrides[get_settings] = lambda: settings
    with TestClient(app) as c:
        yield c


COMMON = ["--map", "room", "--particles", "500", "--pace", "0", "--json", "--temperature",
          "22", "--static", "gated", "--sonar-height", "0.3", "--ceiling-height", "2.6"]


def _lines(out: str) -> list[dict[str, object]]:
    return [json.loads(line) for line in out.splitlines() if line.strip()]


def test_stream_a_wav_tracks_the_logged_poses(files: tuple[Path, Path], client: TestClient,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    wav, poses = files
    args = build_parser().parse_args(["stream", "--wav", str(wav), "--poses", str(poses),
                                      *COMMON])
    assert _cmd_stream(args, http=client) == 0
    lines = _lines(capsys.readouterr().out)
    assert [ln["seq"] for ln in lines] == list(range(len(lines))) and len(lines) >= 6
    errors = [float(ln["log_error_m"]) for ln in lines]  # type: ignore[arg-type]
    assert max(errors) < 0.05, errors
    assert len(client.app.state.sessions) == 0  # type: ignore[attr-defined]  # closed at the end


def test_stream_from_stdin_pcm_gives_the_same_blocks(files: tuple[Path, Path],
                                                     client: TestClient,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    wav, poses = files
    args = build_parser().parse_args(["stream", "--wav", str(wav), "--poses", str(poses),
                                      *COMMON])
    _cmd_stream(args, http=client)
    from_wav = _lines(capsys.readouterr().out)
    rec = recording()
    pcm = np.round(rec.samples / np.abs(rec.samples).max() * 0.5 * 32767).astype("<i2")
    args = build_parser().parse_args(["stream", "--stdin", "--rate", "48000", "--poses",
                                      str(poses), *COMMON])
    _cmd_stream(args, http=client, stdin=io.BytesIO(pcm.tobytes()))
    from_stdin = _lines(capsys.readouterr().out)
    assert len(from_stdin) == len(from_wav)
    for a, b in zip(from_wav, from_stdin, strict=True):
        assert a["seq"] == b["seq"] and abs(float(a["t_s"]) - float(b["t_s"])) < 1e-6  # type: ignore[arg-type]
        assert float(b["log_error_m"]) < 0.05  # type: ignore[arg-type]


def test_stream_refusals(files: tuple[Path, Path], client: TestClient) -> None:
    wav, poses = files
    parse = build_parser().parse_args
    with pytest.raises(ValueError, match="--rate"):
        _cmd_stream(parse(["stream", "--stdin", "--poses", str(poses)]), http=client)
    with pytest.raises(ValueError, match="--pace"):
        _cmd_stream(parse(["stream", "--wav", str(wav), "--poses", str(poses), "--pace", "-1"]),
                    http=client)
    with pytest.raises(ValueError, match="calibration"):
        _cmd_stream(parse(["stream", "--wav", str(wav), "--poses", str(poses), "--static",
                           "calibration"]), http=client)
    with pytest.raises(ValueError, match="omnisonar serve"):  # nothing listens on port 9
        _cmd_stream(parse(["stream", "--wav", str(wav), "--poses", str(poses), "--pace", "0",
                           "--url", "http://127.0.0.1:9"]))
    silence = io.BytesIO(np.zeros(48_000 * 4, dtype="<i2").tobytes())
    with pytest.raises(ValueError, match="direct path"):
        _cmd_stream(parse(["stream", "--stdin", "--rate", "48000", "--poses", str(poses)]),
                    http=client, stdin=silence)


def test_session_speed_of_sound_reaches_the_filter(client: TestClient) -> None:
    """``sound_speed_m_s`` at creation: shown back, used by the session's heat map and echo
    model (the map's shared tables keep the map's), kept in the spec a checkpoint restores."""
    from service.sessions import FilterSpec

    r = client.post("/sessions", json={"map_id": "room", "particles": 100,
                                       "sound_speed_m_s": 344.4,
                                       "initial_pose": {"x": 1.0, "y": 1.0, "yaw": 0.4}})
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    assert client.get(f"/sessions/{sid}").json()["sound_speed_m_s"] == 344.4
    tracker = client.app.state.sessions.get(sid).tracker  # type: ignore[attr-defined]
    assert tracker.config.sound_speed_m_s == 344.4
    assert tracker.tables.sonar.sound_speed_m_s == 344.4
    assert tracker.filter.tables.sonar.sound_speed_m_s == 344.4
    assert tracker.base_tables.sonar.sound_speed_m_s == SonarConfig().sound_speed_m_s
    spec = client.app.state.sessions.get(sid).spec  # type: ignore[attr-defined]
    assert FilterSpec.from_dict(spec.to_dict()).sound_speed_m_s == 344.4
    bad = client.post("/sessions", json={"map_id": "room", "sound_speed_m_s": 250.0})
    assert bad.status_code == 422 and "sound_speed_m_s" in bad.text


def test_stream_temperature_reaches_the_service(files: tuple[Path, Path], client: TestClient,
                                                tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Air at 40 C (355 m/s, 4.5 % above the map's 340): ``--temperature 40`` makes the
    service process the blocks at that speed too; without it (the session at the map's speed,
    only the import's timing corrected) the track is worse."""
    import dataclasses

    import service.commands.stream as stream_module

    hot = dataclasses.replace(RAW, temperature_c=40.0)
    rec = simulate_raw(builtin_scene("shoebox"), builtin_path("shoebox-straight"),
                       SonarConfig(), 8.5, IsmConfig(max_order=2, max_path_m=12.0), hot,
                       np.random.default_rng(2))
    wav = tmp_path / "hot.wav"
    write_wav(wav, rec.samples / np.abs(rec.samples).max() * 0.5, rec.fs_hz)
    common = [a if a != "22" else "40" for a in COMMON]
    args = build_parser().parse_args(["stream", "--wav", str(wav), "--poses", str(files[1]),
                                      *common])
    assert _cmd_stream(args, http=client) == 0
    told = [float(ln["log_error_m"]) for ln in _lines(capsys.readouterr().out)]  # type: ignore[arg-type]
    untold = stream_module._open
    monkeypatch.setattr(stream_module, "_open",
                        lambda c, a, s, speed: untold(c, a, s, None))
    assert _cmd_stream(args, http=client) == 0
    not_told = [float(ln["log_error_m"]) for ln in _lines(capsys.readouterr().out)]  # type: ignore[arg-type]
    assert max(told) < 0.05 and np.mean(told) < np.mean(not_told), (told, not_told)


def test_session_heights_reach_the_echo_model(client: TestClient) -> None:
    """``sonar_height_m`` / ``ceiling_height_m`` at creation reach the session's sensor
    config (the map's shared tables stay 2-D), survive the spec's round trip, and a
    ceiling below the sonar is refused naming the field."""
    from service.sessions import FilterSpec

    r = client.post("/sessions", json={"map_id": "room", "particles": 100,
                                       "sonar_height_m": 0.3, "ceiling_height_m": 2.6,
                                       "initial_pose": {"x": 1.0, "y": 1.0, "yaw": 0.4}})
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    info = client.get(f"/sessions/{sid}").json()
    assert (info["sonar_height_m"], info["ceiling_height_m"]) == (0.3, 2.6)
    session = client.app.state.sessions.get(sid)  # type: ignore[attr-defined]
    assert session.tracker.tables.config.vertical()[0].size == 3
    assert session.tracker.base_tables.config.sonar_height_m is None
    spec = FilterSpec.from_dict(session.spec.to_dict())
    assert (spec.sonar_height_m, spec.ceiling_height_m) == (0.3, 2.6)
    bad = client.post("/sessions", json={"map_id": "room", "sonar_height_m": 2.0,
                                         "ceiling_height_m": 1.0})
    assert bad.status_code == 422 and "ceiling_height_m" in bad.text


def test_session_open_map_reaches_the_filter(client: TestClient) -> None:
    """``open_map`` at creation (issue 14: what a global start on a map with an open wall end
    reports) reaches the session's filter config, is echoed by the session, survives the
    spec's round trip and defaults to "uncertain"; another value is refused naming it."""
    from service.sessions import FilterSpec

    r = client.post("/sessions", json={"map_id": "room", "particles": 100, "global": True,
                                       "open_map": "confirm"})
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    assert client.get(f"/sessions/{sid}").json()["open_map"] == "confirm"
    session = client.app.state.sessions.get(sid)  # type: ignore[attr-defined]
    assert session.tracker.filter.config.open_map_global == "confirm"
    assert FilterSpec.from_dict(session.spec.to_dict()).open_map == "confirm"
    plain = client.post("/sessions", json={"map_id": "room", "particles": 100, "global": True})
    assert plain.json()["open_map"] == "uncertain"
    bad = client.post("/sessions", json={"map_id": "room", "open_map": "never"})
    assert bad.status_code == 422 and "open_map" in bad.text
