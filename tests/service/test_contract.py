"""Strict inputs, no leaks and a true contract (issue 17): one test per defect found."""

from __future__ import annotations

import base64
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from mapping.signal import SonarConfig
from service.app import create_app
from service.settings import Settings
from tests.service.helpers import TRACKED, map_file_bytes

CFG = SonarConfig()
B = CFG.block_samples


@pytest.fixture()
def settings(tmp_path: Path) -> Settings:
    maps = tmp_path / "maps"
    maps.mkdir()
    (maps / "room.npz").write_bytes(map_file_bytes())
    return Settings(maps_dir=maps, sessions_dir=tmp_path / "sessions", runs_dir=tmp_path / "runs",
                    default_map=False, max_body_bytes=256 * 1024, max_map_bytes=4 << 20,
                    max_seq_gap=100)


@pytest.fixture()
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as c:
        yield c


def block(seed: int) -> bytes:
    return (0.01 * np.random.default_rng(seed).standard_normal(B)).astype("<f4").tobytes()


def post_raw(client: TestClient, sid: str, seq: Any, **params: Any) -> Any:
    q = {"seq": seq, "fs_hz": CFG.fs_hz, "speed_m_s": 0.1, **params}
    return client.post(f"/sessions/{sid}/blocks", params=q, content=block(0),
                       headers={"content-type": "application/octet-stream"})


def new_session(client: TestClient) -> str:
    r = client.post("/sessions", json={**TRACKED, "particles": 100})
    assert r.status_code == 201, r.text
    return str(r.json()["id"])


@pytest.mark.parametrize("patch, field", [
    ({"particles": "2000"}, "particles"),
    ({"global": "yes", "initial_pose": None, "initial_covariance": None}, "global"),
    ({"seed": True}, "seed"),
    ({"seed": 1.0}, "seed"),
    ({"initial_pose": {"x": "1", "y": 1.5, "yaw": 0}}, "initial_pose.x"),
])
def test_coerced_values_refused(client: TestClient, patch: dict[str, Any], field: str) -> None:
    r = client.post("/sessions", json={**TRACKED, **patch})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == field and r.json()["allowed"]


@pytest.mark.parametrize("seq", ["1_0", "true", " 5", "+5", "0x1", "5.0"])
def test_query_seq_is_digits_only(client: TestClient, seq: str) -> None:
    sid = new_session(client)
    r = post_raw(client, sid, seq)
    assert r.status_code == 422 and r.json()["field"] == "seq", r.text


def test_json_seq_true_refused(client: TestClient) -> None:
    sid = new_session(client)
    body = {"seq": True, "fs_hz": CFG.fs_hz, "speed_m_s": 0.1,
            "samples_b64": base64.b64encode(block(0)).decode()}
    r = client.post(f"/sessions/{sid}/blocks", json=body)
    assert r.status_code == 422 and r.json()["field"] == "seq", r.text


def test_huge_seq_cannot_brick_a_session(client: TestClient) -> None:
    sid = new_session(client)
    assert post_raw(client, sid, 0).status_code == 200
    r = post_raw(client, sid, 2**53 - 1)
    assert r.status_code == 409, r.text
    assert r.json()["field"] == "seq" and r.json()["allowed"] == "1 <= seq <= 100"
    assert post_raw(client, sid, 1).status_code == 200  # the session goes on
    assert post_raw(client, sid, 101).status_code == 200  # a gap within the window is fine
    assert post_raw(client, sid, 101).status_code == 409
    first = new_session(client)
    r = post_raw(client, first, 10**9)  # the first block too: 0 .. gap
    assert r.status_code == 409 and r.json()["allowed"] == "0 <= seq <= 100"


def test_initial_pose_off_the_map_refused(client: TestClient) -> None:
    extent = client.get("/maps/room").json()["extent_m"]
    r = client.post("/sessions", json={**TRACKED, "initial_pose": {"x": 1e4, "y": 1.0,
                                                                   "yaw": 0.0}})
    assert r.status_code == 422 and r.json()["field"] == "initial_pose.x", r.text
    assert f"{extent[0]:.3f}" in r.json()["allowed"] and f"{extent[1]:.3f}" in r.json()["allowed"]
    r = client.post("/sessions", json={**TRACKED, "initial_pose": {"x": 1.0, "y": -50.0,
                                                                   "yaw": 0.0}})
    assert r.status_code == 422 and r.json()["field"] == "initial_pose.y"
    assert client.get("/health").json()["sessions"] == 0


def test_no_error_body_names_a_server_path(client: TestClient, settings: Settings) -> None:
    root = str(settings.maps_dir.parent)
    answers = [
        client.post("/maps/build", json={"runs": ["missing"], "map_id": "b"}),
        client.post("/maps", params={"map_id": "x"}, content=b"PK garbage"),
        client.post("/maps", params={"map_id": "x"}, content=map_file_bytes()[:-10]),
        client.post("/sessions", json={**TRACKED, "map_id": "nope"}),
        client.get("/maps/nope"), client.get("/jobs/nope"), client.get("/sessions/nope"),
    ]
    for r in answers:
        assert 400 <= r.status_code < 500
        assert root not in r.text and not re.search(r"(/[\w.-]+){3,}", r.text), r.text


def test_scrub_paths() -> None:
    from service.errors import scrub_paths

    assert scrub_paths("no file /srv/omni/maps/.x.upload.npz here") == \
        "no file .x.upload.npz here"
    assert scrub_paths("speed 0.1 m/s, files in /srv/runs/") == "speed 0.1 m/s, files in runs"
    assert scrub_paths("GET /maps") == "GET /maps"


def test_422_documented_as_the_real_error_body(client: TestClient) -> None:
    doc = client.get("/openapi.json").json()
    assert "HTTPValidationError" not in str(doc)
    post = doc["paths"]["/sessions"]["post"]["responses"]
    assert post["422"]["content"]["application/json"]["schema"]["$ref"].endswith("/ErrorBody")
    for code in ("400", "401", "408", "413", "429"):
        assert code in post, code
    r = client.post("/sessions", json={**TRACKED, "particles": "x"})
    assert set(r.json()) >= {"error", "detail", "field", "allowed"}


def test_undecodable_json_is_documented_400(client: TestClient) -> None:
    r = client.post("/sessions", content=b'{"map_id": "\xff"}',
                    headers={"content-type": "application/json"})
    assert r.status_code in (400, 422) and r.json()["error"]
    ops = client.get("/openapi.json").json()["paths"]
    assert str(r.status_code) in ops["/sessions"]["post"]["responses"]


def test_405_allow_lists_every_method_of_the_path(client: TestClient) -> None:
    r = client.put("/sessions/abc")
    assert r.status_code == 405
    assert set(r.headers["allow"].split(", ")) == {"GET", "DELETE"}
    r = client.delete("/maps")
    assert r.status_code == 405 and set(r.headers["allow"].split(", ")) == {"GET", "POST"}


def test_slow_body_is_408(settings: Settings) -> None:
    import asyncio

    app = create_app(settings.model_copy(update={"read_timeout_s": 0.2}))
    sent: list[dict[str, Any]] = []

    async def run() -> None:
        async with app.router.lifespan_context(app):
            app.state  # noqa: B018 (lifespan set the stores)
            calls = 0

            async def receive() -> dict[str, Any]:
                nonlocal calls
                calls += 1
                if calls == 1:
                    return {"type": "http.request", "body": b"{", "more_body": True}
                await asyncio.sleep(5)  # the client stalls mid-body
                return {"type": "http.disconnect"}

            async def send(msg: dict[str, Any]) -> None:
                sent.append(msg)

            scope = {"type": "http", "method": "POST", "path": "/sessions", "raw_path":
                     b"/sessions", "query_string": b"", "root_path": "", "scheme": "http",
                     "headers": [(b"content-type", b"application/json")], "client":
                     ("127.0.0.1", 1), "server": ("127.0.0.1", 80), "http_version": "1.1",
                     "asgi": {"version": "3.0"}, "state": {}}
            await asyncio.wait_for(app(scope, receive, send), 3)  # type: ignore[arg-type]

    asyncio.run(run())
    assert sent[0]["status"] == 408
