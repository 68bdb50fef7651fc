"""HTTP API with FastAPI's TestClient: every endpoint and error path, on the real filter.

The map is a small real WallMap: the walls of the built-in ``shoebox`` scene rasterized at
5 cm. Error-path tests compare the session (its JSON and its checkpoint file, byte for byte)
before and after each rejected request.
"""

from __future__ import annotations

import base64
import io
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from mapping.files import write_map
from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from service.app import create_app
from service.settings import Settings, get_settings
from tests.service.helpers import TRACKED, raster_map

CFG = SonarConfig()
B = CFG.block_samples




def noise_block(seed: int, scale: float = 0.01) -> np.ndarray:
    return (scale * np.random.default_rng(seed).standard_normal(B)).astype("<f4")


@pytest.fixture(scope="module")
def map_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    p = tmp_path_factory.mktemp("m") / "room.npz"
    write_map(p, raster_map())
    return p.read_bytes()


@pytest.fixture()
def settings(tmp_path: Path, map_bytes: bytes) -> Settings:
    maps = tmp_path / "maps"
    maps.mkdir()
    (maps / "room.npz").write_bytes(map_bytes)
    return Settings(maps_dir=maps, sessions_dir=tmp_path / "sessions", runs_dir=tmp_path / "runs",
                    default_map=False, max_sessions=3, max_particles=5000,
                    max_body_bytes=256 * 1024, max_map_bytes=4 << 20)


@pytest.fixture()
def client(settings: Settings) -> Iterator[TestClient]:
    app = create_app()
    app.dependency_overrides[get_settings] = lambda: settings
    with TestClient(app) as c:
        yield c




def new_session(client: TestClient, **over: Any) -> str:
    r = client.post("/sessions", json={**TRACKED, **over})
    assert r.status_code == 201, r.text
    return str(r.json()["id"])


def post_raw(client: TestClient, sid: str, seq: Any, data: bytes, **params: Any) -> Any:
    q = {"seq": seq, "fs_hz": CFG.fs_hz, "speed_m_s": 0.2, "yaw_rate_rad_s": 0.1, **params}
    return client.post(f"/sessions/{sid}/blocks", params=q, content=data,
                       headers={"content-type": "application/octet-stream"})


def snapshot(client: TestClient, settings: Settings, sid: str) -> tuple[Any, bytes]:
    info = client.get(f"/sessions/{sid}").json()
    for k in ("expires_in_s", "last_active_at"):
        info.pop(k)
    return info, (settings.sessions_path / f"{sid}.npz").read_bytes()


# ---- maps ---------------------------------------------------------------------------------
def test_maps_list_get_image(client: TestClient) -> None:
    r = client.get("/maps")
    assert r.status_code == 200
    (info,) = r.json()["maps"]
    assert info["id"] == "room" and info["resolution_m"] == pytest.approx(0.05)
    assert info["sonar"]["fs_hz"] == CFG.fs_hz
    assert client.get("/maps/room").json() == info
    img = client.get("/maps/room/image.png")
    assert img.status_code == 200 and img.headers["content-type"] == "image/png"
    assert img.content[:8] == b"\x89PNG\r\n\x1a\n"
    from matplotlib.image import imread

    assert imread(io.BytesIO(img.content)).shape[:2] == tuple(info["shape"])
    for path in ("/maps/nope", "/maps/nope/image.png"):
        r = client.get(path)
        assert r.status_code == 404 and r.json()["field"] == "map_id"


def test_map_upload_validated_and_atomic(client: TestClient, settings: Settings,
                                         map_bytes: bytes) -> None:
    ok = client.post("/maps", params={"map_id": "copy"}, content=map_bytes,
                     headers={"content-type": "application/octet-stream"})
    assert ok.status_code == 201 and ok.json()["id"] == "copy"
    assert (settings.maps_dir / "copy.npz").read_bytes() == map_bytes
    again = client.post("/maps", params={"map_id": "copy"}, content=map_bytes)
    assert again.status_code == 409
    bad = client.post("/maps", params={"map_id": "broken"}, content=map_bytes[:-100])
    assert bad.status_code == 422 and bad.json()["field"] == "body"
    assert not (settings.maps_dir / "broken.npz").exists()
    assert not [p for p in settings.maps_dir.iterdir() if p.name.startswith(".")]
    assert client.post("/maps", params={"map_id": "../x"}, content=map_bytes).status_code == 422
    assert client.post("/maps", params={"map_id": "e"}, content=b"").status_code == 422
    over = client.post("/maps", params={"map_id": "copy", "overwrite": True}, content=map_bytes)
    assert over.status_code == 201


def test_map_build_validation(client: TestClient) -> None:
    r = client.post("/maps/build", json={"runs": ["missing"], "map_id": "b"})
    assert r.status_code == 422 and r.json()["field"] == "runs.0"
    r = client.post("/maps/build", json={"runs": [], "map_id": "b"})
    assert r.status_code == 422 and r.json()["field"] == "runs"
    assert client.get("/jobs/nope").status_code == 404


# ---- sessions -----------------------------------------------------------------------------
def test_session_lifecycle(client: TestClient, settings: Settings) -> None:
    r = client.post("/sessions", json=TRACKED)
    assert r.status_code == 201
    body = r.json()
    sid = body["id"]
    assert r.headers["location"] == f"/sessions/{sid}"
    assert body["last_seq"] is None and body["estimate"] is None and body["filter"] == "pf"
    assert (settings.sessions_path / f"{sid}.npz").exists()
    parts = client.get(f"/sessions/{sid}/particles", params={"max": 50}).json()
    assert parts["n_total"] == 300 and len(parts["x"]) == 50
    assert abs(np.mean(parts["x"]) - 1.0) < 0.05 and abs(np.mean(parts["y"]) - 1.5) < 0.05
    assert all(-math.pi < a <= math.pi for a in parts["yaw"])
    assert client.delete(f"/sessions/{sid}").status_code == 204
    assert not (settings.sessions_path / f"{sid}.npz").exists()
    assert client.get(f"/sessions/{sid}").status_code == 404


def test_global_session_spreads_over_map(client: TestClient) -> None:
    sid = new_session(client, initial_pose=None, initial_covariance=None, **{"global": True})
    p = client.get(f"/sessions/{sid}/particles", params={"max": 300}).json()
    x, y = np.asarray(p["x"]), np.asarray(p["y"])
    assert 0 < x.min() and x.max() < 4 and 0 < y.min() and y.max() < 3  # inside the room
    assert x.std() > 0.7 and y.std() > 0.5


@pytest.mark.parametrize("body, field", [
    ({"particles": 6000}, "particles"),
    ({"particles": 5}, "particles"),
    ({"map_id": "nope"}, "map_id"),
    ({"map_id": "a/b"}, "map_id"),
    ({"filter": "kalman"}, "filter"),
    ({"seed": -1}, "seed"),
    ({"initial_pose": {"x": 1, "y": 2}}, "initial_pose.yaw"),
    ({"initial_pose": {"x": 1e9, "y": 2, "yaw": 0}}, "initial_pose.x"),
    ({"initial_covariance": [[1, 0], [0, 1]]}, "initial_covariance"),
    ({"initial_covariance": [[1, 2, 0], [0, 1, 0], [0, 0, 1]]}, "initial_covariance"),
    ({"initial_covariance": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "initial_covariance"),
    ({"unknown": 1}, "unknown"),
    ({"beta": 0}, "beta"),
    ({"beta": 1e6}, "beta"),
])
def test_session_create_rejects(client: TestClient, body: dict[str, Any], field: str) -> None:
    r = client.post("/sessions", json={**TRACKED, **body})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == field
    assert client.get("/health").json()["sessions"] == 0


def test_session_cap(client: TestClient) -> None:
    for _ in range(3):
        new_session(client)
    r = client.post("/sessions", json=TRACKED)
    assert r.status_code == 429 and "max_sessions" in r.json()["detail"]


# ---- blocks -------------------------------------------------------------------------------
def check_estimate(e: dict[str, Any], seq: int) -> None:
    assert e["seq"] == seq and e["frame_id"] == "map"
    assert -math.pi < e["pose"]["yaw"] <= math.pi
    c3, c6 = np.asarray(e["covariance"]), np.asarray(e["covariance_ros"]).reshape(6, 6)
    np.testing.assert_allclose(c6[np.ix_([0, 1, 5], [0, 1, 5])], c3)
    assert np.all(np.linalg.eigvalsh(c3) > -1e-12)
    assert e["modes"] and abs(sum(m["weight"] for m in e["modes"]) - 1) < 0.05 + 1e-9
    assert 1 <= e["ess"] <= 300 + 1e-6 and e["processing_ms"] > 0
    assert e["direction_observable"] is True
    assert 0.0 < e["likelihood_scale"] <= 1.0


def test_blocks_in_three_encodings(client: TestClient) -> None:
    sid = new_session(client)
    r = post_raw(client, sid, 0, noise_block(0).tobytes())
    assert r.status_code == 200, r.text
    check_estimate(r.json(), 0)
    pcm = (noise_block(1) * 32768 * 10).astype("<i2").tobytes()
    r = post_raw(client, sid, 1, pcm, encoding="int16")
    assert r.status_code == 200, r.text
    check_estimate(r.json(), 1)
    r = client.post(f"/sessions/{sid}/blocks", json={
        "seq": 2, "fs_hz": CFG.fs_hz, "speed_m_s": 0.2, "yaw_rate_rad_s": 0.0,
        "samples_b64": base64.b64encode(noise_block(2).tobytes()).decode()})
    assert r.status_code == 200, r.text
    check_estimate(r.json(), 2)
    r = post_raw(client, sid, 3, noise_block(3).tobytes(), yaw_rate_rad_s=-0.1)
    assert r.status_code == 200, r.text
    check_estimate(r.json(), 3)
    info = client.get(f"/sessions/{sid}").json()
    assert info["last_seq"] == 3 and info["n_updates"] == 4 and info["estimate"]["seq"] == 3


def test_one_way_to_send_each_field(client: TestClient, settings: Settings) -> None:
    """Raw blocks take their odometry as query parameters only (the X-Omnisonar-* headers
    are gone), JSON blocks in the body only; either mistake is a 422 naming the field."""
    sid = new_session(client)
    before = snapshot(client, settings, sid)
    hdr = {"content-type": "application/octet-stream", "x-omnisonar-seq": "0",
           "x-omnisonar-fs-hz": str(CFG.fs_hz), "x-omnisonar-speed-m-s": "0.2"}
    r = client.post(f"/sessions/{sid}/blocks", content=noise_block(0).tobytes(), headers=hdr)
    assert r.status_code == 422 and r.json()["field"] == "seq", r.text
    assert "?seq=" in r.json()["allowed"]
    r = client.post(f"/sessions/{sid}/blocks", params={"seq": 0, "fs_hz": CFG.fs_hz},
                    content=noise_block(0).tobytes(),
                    headers={"content-type": "application/octet-stream"})
    assert r.status_code == 422 and r.json()["field"] == "speed_m_s", r.text
    body = {"seq": 0, "fs_hz": CFG.fs_hz, "speed_m_s": 0.2,
            "samples_b64": base64.b64encode(noise_block(0).tobytes()).decode()}
    r = client.post(f"/sessions/{sid}/blocks", json=body, params={"encoding": "int16"})
    assert r.status_code == 422 and r.json()["field"] == "encoding", r.text
    assert snapshot(client, settings, sid) == before
    assert client.post(f"/sessions/{sid}/blocks", json=body).status_code == 200


def test_empty_block_predicts_only(client: TestClient) -> None:
    sid = new_session(client)
    r = post_raw(client, sid, 0, b"", speed_m_s=0.0, yaw_rate_rad_s=0.0)
    assert r.status_code == 200, r.text
    assert r.json()["direction_observable"] is False


BAD_BLOCKS: list[tuple[str, dict[str, Any], bytes | None, int, str]] = [  # noqa: E501
    ("duplicate seq", {"seq": 0}, None, 409, "seq"),
    ("short block", {}, noise_block(5)[:-1].tobytes(), 422, "samples"),
    ("odd bytes", {}, noise_block(5).tobytes()[:-1], 422, "samples"),
    ("nan", {}, np.full(B, np.nan, "<f4").tobytes(), 422, "samples"),
    ("zeros", {}, np.zeros(B, "<f4").tobytes(), 422, "samples"),
    ("clipped", {}, np.sign(noise_block(6)).astype("<f4").tobytes(), 422, "samples"),
    ("fs mismatch", {"fs_hz": 44100.0}, None, 422, "fs_hz"),
    ("speed range", {"speed_m_s": 50.0}, None, 422, "speed_m_s"),
    ("speed nan", {"speed_m_s": "nan"}, None, 422, "speed_m_s"),
    ("yaw rate range", {"yaw_rate_rad_s": -11}, None, 422, "yaw_rate_rad_s"),
    ("seq negative", {"seq": -3}, None, 422, "seq"),
    ("seq type", {"seq": "x"}, None, 422, "seq"),
    ("encoding", {"encoding": "float64"}, None, 422, "encoding"),
]


@pytest.mark.parametrize("name, params, data, status, field", BAD_BLOCKS,
                         ids=[b[0] for b in BAD_BLOCKS])
def test_rejected_block_leaves_session_untouched(
    client: TestClient, settings: Settings, name: str, params: dict[str, Any],
    data: bytes | None, status: int, field: str,
) -> None:
    sid = new_session(client)
    first = post_raw(client, sid, 0, noise_block(0).tobytes())
    assert first.status_code == 200, first.text
    before = snapshot(client, settings, sid)
    q = {"seq": 1, **params}
    r = post_raw(client, sid, q.pop("seq"), noise_block(1).tobytes() if data is None else data,
                 **q)
    assert r.status_code == status, r.text
    body = r.json()
    assert body["field"] == field and body["detail"]
    if status == 422 and field != "samples":
        assert body["allowed"]
    assert snapshot(client, settings, sid) == before
    ok = post_raw(client, sid, 1, noise_block(1).tobytes())  # seq 1 is still free
    assert ok.status_code == 200


def test_missing_params_and_bad_json(client: TestClient, settings: Settings) -> None:
    sid = new_session(client)
    before = snapshot(client, settings, sid)
    r = client.post(f"/sessions/{sid}/blocks", params={"fs_hz": 40000, "speed_m_s": 0.1},
                    content=noise_block(0).tobytes())
    assert r.status_code == 422 and r.json()["field"] == "seq"
    good: dict[str, Any] = {"seq": 0, "fs_hz": CFG.fs_hz, "speed_m_s": 0.2,
            "samples_b64": base64.b64encode(noise_block(0).tobytes()).decode()}
    patches: list[tuple[dict[str, Any], str]] = [({"samples_b64": "***"}, "samples_b64"),
                         ({"speed_m_s": "fast"}, "speed_m_s"), ({"extra": 1}, "extra"),
                         ({"samples_b64": base64.b64encode(b"abc").decode()}, "samples")]
    for patch, field in patches:
        r = client.post(f"/sessions/{sid}/blocks", json={**good, **patch})
        assert r.status_code == 422 and r.json()["field"] == field, r.text
    r = client.post(f"/sessions/{sid}/blocks", content=b"{not json",
                    headers={"content-type": "application/json"})
    assert r.status_code == 422
    r = client.post(f"/sessions/{sid}/blocks", content=b"x", headers={"content-type": "text/csv"})
    assert r.status_code == 415
    assert snapshot(client, settings, sid) == before


def test_body_limit_413(client: TestClient, settings: Settings) -> None:
    sid = new_session(client)
    before = snapshot(client, settings, sid)
    big = b"\0" * (settings.max_body_bytes + 1)
    r = post_raw(client, sid, 0, big)
    assert r.status_code == 413 and r.json()["field"] == "body"

    def chunks() -> Iterator[bytes]:  # no Content-Length: the streamed count must trip
        for _ in range(5):
            yield b"\0" * (settings.max_body_bytes // 4)

    r = client.post(f"/sessions/{sid}/blocks", params={"seq": 0, "fs_hz": 40000,
                                                       "speed_m_s": 0},
                    content=chunks(), headers={"content-type": "application/octet-stream"})
    assert r.status_code == 413
    r = client.post("/sessions", content=b" " * (settings.max_body_bytes + 1),
                    headers={"content-type": "application/json"})
    assert r.status_code == 413
    assert snapshot(client, settings, sid) == before


def test_unknown_session_404(client: TestClient) -> None:
    for method, path in [("GET", "/sessions/x"), ("DELETE", "/sessions/x"),
                         ("POST", "/sessions/x/global"), ("GET", "/sessions/x/particles"),
                         ("POST", "/sessions/x/blocks")]:
        r = client.request(method, path, params={"seq": 0, "fs_hz": 40000, "speed_m_s": 0},
                           content=noise_block(0).tobytes())
        assert r.status_code == 404, (method, path)
        assert r.json()["field"] == "session_id"


def test_global_reinit_and_particles_bounds(client: TestClient) -> None:
    sid = new_session(client)
    assert post_raw(client, sid, 0, noise_block(0).tobytes()).status_code == 200
    r = client.post(f"/sessions/{sid}/global")
    assert r.status_code == 200
    assert r.json()["estimate"] is None and r.json()["last_seq"] == 0
    x = np.asarray(client.get(f"/sessions/{sid}/particles", params={"max": 300}).json()["x"])
    assert x.std() > 0.7
    assert post_raw(client, sid, 0, noise_block(0).tobytes()).status_code == 409
    assert post_raw(client, sid, 1, noise_block(1).tobytes()).status_code == 200
    for bad in (0, -1, 10**6, "a"):
        r = client.get(f"/sessions/{sid}/particles", params={"max": bad})
        assert r.status_code == 422 and r.json()["field"] == "max"


def test_restart_reloads_sessions(settings: Settings) -> None:
    app = create_app(settings)
    with TestClient(app) as c:
        sid = new_session(c)
        for k in range(2):
            assert post_raw(c, sid, k, noise_block(k).tobytes()).status_code == 200
        before = c.get(f"/sessions/{sid}").json()
    with TestClient(create_app(settings)) as c:
        after = c.get(f"/sessions/{sid}").json()
        assert after["last_seq"] == 1 and after["estimate"] == before["estimate"]
        assert post_raw(c, sid, 1, noise_block(1).tobytes()).status_code == 409
        assert post_raw(c, sid, 2, noise_block(2).tobytes()).status_code == 200


def test_session_beta_applies_and_survives_restart(settings: Settings) -> None:
    """A session may ask for its own sensor sharpness (e.g. from ``omnisonar calibrate``):
    the info reports it, a sharper beta gives a tighter best-mode covariance on the same
    blocks and seed, and a restarted server restores the session with that beta."""
    blocks = [noise_block(k) for k in range(3)]

    def run(c: TestClient, beta: float | None) -> tuple[str, Any]:
        sid = new_session(c, **({} if beta is None else {"beta": beta}))
        info = c.get(f"/sessions/{sid}").json()
        assert info["beta"] == beta
        for k, b in enumerate(blocks):
            r = post_raw(c, sid, k, b.tobytes())
            assert r.status_code == 200, r.text
        return sid, np.asarray(r.json()["covariance"])

    app = create_app(settings)
    with TestClient(app) as c:
        sid, soft = run(c, 20.0)
        _, sharp = run(c, 2000.0)
        assert np.trace(sharp[:2, :2]) < np.trace(soft[:2, :2])
        before = c.get(f"/sessions/{sid}").json()
    with TestClient(create_app(settings)) as c:
        after = c.get(f"/sessions/{sid}").json()
        assert after["beta"] == 20.0 and after["estimate"] == before["estimate"]
        assert post_raw(c, sid, 3, noise_block(3).tobytes()).status_code == 200


def test_openapi_documents_both_block_bodies(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    body = spec["paths"]["/sessions/{session_id}/blocks"]["post"]["requestBody"]["content"]
    assert body["application/octet-stream"]["schema"]["format"] == "binary"
    assert "samples_b64" in body["application/json"]["schema"]["properties"]
    params = {p["name"] for p in spec["paths"]["/sessions/{session_id}/blocks"]["post"]
              ["parameters"]}
    assert params == {"session_id", "seq", "fs_hz", "speed_m_s", "yaw_rate_rad_s", "encoding"}
    assert "application/octet-stream" in spec["paths"]["/maps"]["post"]["requestBody"]["content"]


def test_estimate_model_is_the_one_conversion() -> None:
    """Core PoseEstimate -> response: yaw wrapped, modes, and the ROS 6x6 layout (x, y, z,
    roll, pitch, yaw; z/roll/pitch rows and columns zero, as AMCL)."""
    from localization.estimate import Mode, PoseEstimate
    from service.routers.sessions import estimate_model

    cov = np.array([[1.0, 0.1, 0.2], [0.1, 2.0, 0.3], [0.2, 0.3, 3.0]])
    est = PoseEstimate(pose=np.array([1.0, 2.0, 3 * math.pi]), cov=cov, mean_all=np.zeros(3),
                       cov_all=2 * cov, modes=(Mode(1.0, np.array([1.0, 2.0, -math.pi]), cov),),
                       ess=5.0, converged=False, direction_observable=True, updated=True,
                       model="correlation", likelihood_scale=0.5)
    e = estimate_model("s", 4, est, 7.0)
    assert e.pose.yaw == pytest.approx(math.pi) and e.modes[0].pose.yaw == math.pi
    c6 = np.asarray(e.covariance_ros).reshape(6, 6)
    assert c6[0, 0] == 1.0 and c6[1, 1] == 2.0 and c6[5, 5] == 3.0
    assert c6[0, 5] == 0.2 and c6[5, 1] == 0.3 and c6[0, 1] == 0.1
    assert np.all(c6[2:5, :] == 0) and np.all(c6[:, 2:5] == 0)
    assert e.covariance == cov.tolist() and e.covariance_all == (2 * cov).tolist()
    assert (e.seq, e.ess, e.likelihood_scale, e.processing_ms) == (4, 5.0, 0.5, 7.0)


def test_grid_filter_session(client: TestClient, settings: Settings) -> None:
    sid = new_session(client, filter="grid")
    r = post_raw(client, sid, 0, noise_block(0).tobytes())
    assert r.status_code == 200, r.text
    e = r.json()
    check_estimate({**e, "ess": min(e["ess"], 300)}, 0)
    # tracked start: the grid posterior stays near the initial pose after one block
    assert math.hypot(e["pose"]["x"] - 1.0, e["pose"]["y"] - 1.5) < 0.3
    r = client.get(f"/sessions/{sid}/particles")
    assert r.status_code == 409 and r.json()["field"] == "session_id"
    before = snapshot(client, settings, sid)
    assert post_raw(client, sid, 0, noise_block(0).tobytes()).status_code == 409
    assert snapshot(client, settings, sid) == before
    singular = client.post("/sessions", json={**TRACKED, "filter": "grid",
                                               "initial_covariance": [[0.0] * 3] * 3})
    assert singular.status_code == 422 and singular.json()["field"] == "initial_covariance"


def _wait_job(client: TestClient, job_id: str, timeout_s: float = 120.0) -> dict[str, Any]:
    import time

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = client.get(f"/jobs/{job_id}").json()
        if job["status"] in ("done", "failed"):
            return dict(job)
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} still running")


def test_map_build_job(client: TestClient, settings: Settings) -> None:
    from mapping.files import write_run
    from mapping.path import builtin_path
    from mapping.simulate import simulate_run
    from mapping.simulate.ism import IsmConfig

    run = simulate_run(builtin_scene("shoebox"), builtin_path("shoebox-curve"), CFG, 3,
                       IsmConfig(order=2), np.random.default_rng(0))  # order 2: fast
    write_run(settings.runs_path / "r1.npz", run)
    r = client.post("/maps/build", json={"runs": ["r1"], "map_id": "built"})
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/jobs/{job['id']}" and job["map_id"] == "built"
    done = _wait_job(client, job["id"])
    assert done["status"] == "done" and done["progress"] == 1.0, done
    info = client.get("/maps/built").json()
    assert info["method"] == "paper" and info["provenance"]
    again = client.post("/maps/build", json={"runs": ["r1"], "map_id": "built"})
    assert again.status_code == 409
    bad = client.post("/maps/build", json={"runs": ["r1"], "map_id": "x", "method": "magic"})
    assert bad.status_code == 422 and bad.json()["field"] == "method"
    sid = new_session(client, map_id="built", initial_pose={"x": 1.0, "y": 1.0, "yaw": 0.0})
    assert post_raw(client, sid, 0, run.samples[0].tobytes(),
                    speed_m_s=float(run.speed_m_s[0])).status_code == 200


def test_default_map_built_in_background(settings: Settings,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    import functools

    from service import builds

    # the real job body on a 4-block run (the full one takes ~20 s)
    monkeypatch.setattr(builds, "simulate_default_run",
                        functools.partial(builds.simulate_default_run, n_blocks=4))
    cfg = settings.model_copy(update={"default_map": True})
    with TestClient(create_app(cfg)) as c:
        building = c.get("/maps").json()["building"]
        if building:  # still running: sessions on it are 503 with Retry-After
            assert building == ["default"]
            r = c.post("/sessions", json={**TRACKED, "map_id": "default"})
            assert r.status_code in (503, 201)
            if r.status_code == 503:
                assert r.headers["retry-after"]
        jobs = c.app.state.jobs  # type: ignore[attr-defined]
        (job_id,) = list(jobs._jobs)
        assert _wait_job(c, job_id)["status"] == "done"
        info = c.get("/maps/default").json()
        assert "paper-b" in info["provenance"]["runs"][0]["path"]
    with TestClient(create_app(cfg)) as c:  # cached: no second build
        assert c.get("/maps").json()["building"] == []
        jobs = c.app.state.jobs  # type: ignore[attr-defined]
        assert list(jobs._jobs) == [job_id]  # only the first build's record, kept on disk
        assert c.get(f"/jobs/{job_id}").json()["status"] == "done"


def test_idle_sessions_expire_in_the_background(settings: Settings) -> None:
    import time

    cfg = settings.model_copy(update={"session_idle_s": 0.5, "expiry_check_s": 0.1})
    with TestClient(create_app(cfg)) as c:
        sid = new_session(c)
        assert (cfg.sessions_path / f"{sid}.npz").exists()
        deadline = time.monotonic() + 10
        while c.get("/health").json()["sessions"] and time.monotonic() < deadline:
            time.sleep(0.1)
        assert c.get(f"/sessions/{sid}").status_code == 404
        assert not (cfg.sessions_path / f"{sid}.npz").exists()
