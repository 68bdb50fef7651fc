"""Access control (issue 17): keys, session ownership, admin-only map writes, the bind rule."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.auth import KeyRing, check_bind, key_name, read_keys_file
from service.sessions import read_checkpoint
from service.settings import Settings
from tests.service.helpers import TRACKED, map_file_bytes

ALICE, BOB = "alice-key-0123456789abcdef", "bob-key-0123456789abcdef"
ADMIN = "admin-key-0123456789ab"


def bearer(key: str) -> dict[str, str]:
    return {"authorization": f"Bearer {key}"}


@pytest.fixture()
def settings(tmp_path: Path) -> Settings:
    maps = tmp_path / "maps"
    maps.mkdir()
    (maps / "room.npz").write_bytes(map_file_bytes())
    return Settings(maps_dir=maps, sessions_dir=tmp_path / "sessions", runs_dir=tmp_path / "runs",
                    default_map=False, max_body_bytes=256 * 1024, max_map_bytes=4 << 20,
                    api_keys=f"{ALICE},{BOB}", admin_keys=ADMIN,  # type: ignore[arg-type]
                    max_sessions_per_key=2)


@pytest.fixture()
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as c:
        yield c


def new_session(client: TestClient, key: str, **over: Any) -> str:
    r = client.post("/sessions", json={**TRACKED, "particles": 100, **over}, headers=bearer(key))
    assert r.status_code == 201, r.text
    return str(r.json()["id"])


def test_no_key_is_401(client: TestClient) -> None:
    for method, path in [("GET", "/maps"), ("GET", "/maps/room"), ("POST", "/sessions"),
                         ("GET", "/sessions/x"), ("POST", "/maps")]:
        r = client.request(method, path)
        assert r.status_code == 401, (method, path, r.text)
        assert r.json()["field"] == "authorization"
        assert r.headers["www-authenticate"].startswith("Bearer")
    assert client.get("/maps", headers=bearer("wrong-key-000000000000")).status_code == 401
    assert client.get("/health").status_code == 200  # liveness stays open
    assert client.get("/openapi.json").status_code == 200


def test_key_in_either_header(client: TestClient) -> None:
    assert client.get("/maps", headers=bearer(ALICE)).status_code == 200
    assert client.get("/maps", headers={"x-api-key": ALICE}).status_code == 200


def test_sessions_belong_to_their_key(client: TestClient) -> None:
    sid = new_session(client, ALICE)
    info = client.get(f"/sessions/{sid}", headers=bearer(ALICE))
    assert info.status_code == 200
    for method, path in [("GET", ""), ("POST", "/global"), ("GET", "/particles"),
                         ("POST", "/blocks"), ("DELETE", "")]:
        r = client.request(method, f"/sessions/{sid}{path}", headers=bearer(BOB),
                           params={"seq": 0, "fs_hz": 40000, "speed_m_s": 0})
        assert r.status_code == 404, (method, path, r.text)  # as if it did not exist
        assert r.json() == client.request(method, f"/sessions/nope{path}", headers=bearer(BOB),
                                          params={"seq": 0, "fs_hz": 40000, "speed_m_s": 0}
                                          ).json() | {"detail": r.json()["detail"]}
    assert client.get(f"/sessions/{sid}", headers=bearer(ADMIN)).status_code == 200
    assert client.delete(f"/sessions/{sid}", headers=bearer(ALICE)).status_code == 204


def test_map_writes_need_an_admin_key(client: TestClient) -> None:
    data = map_file_bytes()
    r = client.post("/maps", params={"map_id": "new"}, content=data, headers=bearer(ALICE))
    assert r.status_code == 403 and r.json()["field"] == "authorization"
    r = client.post("/maps/build", json={"runs": ["r"], "map_id": "b"}, headers=bearer(ALICE))
    assert r.status_code == 403
    assert client.get("/jobs/abc", headers=bearer(ALICE)).status_code == 403
    assert not (client.app.state.settings.maps_dir / "new.npz").exists()  # type: ignore[attr-defined]
    r = client.post("/maps", params={"map_id": "new"}, content=data, headers=bearer(ADMIN))
    assert r.status_code == 201, r.text


def test_per_key_session_quota(client: TestClient) -> None:
    for _ in range(2):
        new_session(client, ALICE)
    r = client.post("/sessions", json={**TRACKED, "particles": 100}, headers=bearer(ALICE))
    assert r.status_code == 429 and "max_sessions_per_key" in r.json()["detail"]
    new_session(client, BOB)  # one key filling its quota locks nobody else out


def test_owner_survives_restart(settings: Settings) -> None:
    with TestClient(create_app(settings)) as c:
        sid = new_session(c, ALICE)
    with TestClient(create_app(settings)) as c:
        assert c.get(f"/sessions/{sid}", headers=bearer(BOB)).status_code == 404
        assert c.get(f"/sessions/{sid}", headers=bearer(ALICE)).status_code == 200
    meta, _ = read_checkpoint(settings.sessions_path / f"{sid}.npz")
    assert meta["owner"] == key_name(ALICE) and ALICE not in str(meta)  # a hash, not the key


def test_open_mode_answers_loopback_clients_only(tmp_path: Path) -> None:
    cfg = Settings(maps_dir=tmp_path / "maps", default_map=False)
    app = create_app(cfg)
    with TestClient(app, client=("127.0.0.1", 5000)) as local:
        assert local.get("/maps").status_code == 200
    with TestClient(app, client=("192.168.1.20", 5000)) as remote:
        r = remote.get("/maps")
        assert r.status_code == 401 and "loopback" in r.json()["detail"]
    insecure = create_app(cfg.model_copy(update={"allow_insecure": True}))
    with TestClient(insecure, client=("192.168.1.20", 5000)) as remote:
        assert remote.get("/maps").status_code == 200


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "192.168.1.20", "robot.local", ""])
def test_non_loopback_bind_without_keys_refused(tmp_path: Path, host: str) -> None:
    cfg = Settings(maps_dir=tmp_path / "maps", host=host)
    with pytest.raises(RuntimeError, match="OMNISONAR_API_KEYS"):
        check_bind(cfg, KeyRing.from_settings(cfg))
    check_bind(cfg.model_copy(update={"allow_insecure": True}), KeyRing([], []))
    check_bind(cfg, KeyRing([ALICE], []))
    with pytest.raises(RuntimeError), TestClient(create_app(cfg)):
        pass  # the app refuses to start too (uvicorn --factory service.app:create_app)


def test_loopback_bind_without_keys_allowed(tmp_path: Path) -> None:
    for host in ("127.0.0.1", "::1", "localhost"):
        cfg = Settings(maps_dir=tmp_path / "maps", host=host)
        check_bind(cfg, KeyRing.from_settings(cfg))


def test_serve_command_refuses_open_network_bind(tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    from service.cli import main

    monkeypatch.delenv("OMNISONAR_API_KEYS", raising=False)
    monkeypatch.delenv("OMNISONAR_ADMIN_KEYS", raising=False)
    assert main(["serve", "--maps", str(tmp_path / "maps"), "--host", "0.0.0.0",
                 "--port", "1"]) == 2


def test_keys_file(tmp_path: Path) -> None:
    f = tmp_path / "keys"
    f.write_text(f"# robots\nuser {ALICE}\nadmin {ADMIN}  # ops\n\n")
    assert read_keys_file(f) == ([ALICE], [ADMIN])
    ring = KeyRing(*read_keys_file(f))
    alice, admin = ring.lookup(ALICE), ring.lookup(ADMIN)
    assert alice is not None and not alice.admin and admin is not None and admin.admin
    assert ring.lookup(BOB) is None
    for bad in ("root " + ALICE, "user short", "user a b"):
        f.write_text(bad)
        with pytest.raises(ValueError, match="line 1") as exc:
            read_keys_file(f)
        assert ALICE not in str(exc.value)


def test_map_delete_needs_an_admin_key(client: TestClient) -> None:
    assert client.delete("/maps/room").status_code == 401
    r = client.delete("/maps/room", headers=bearer(ALICE))
    assert r.status_code == 403 and r.json()["error"] == "forbidden"
    sid = new_session(client, ALICE)
    r = client.delete("/maps/room", headers=bearer(ADMIN))  # Alice's session uses it
    assert r.status_code == 409 and r.json()["error"] == "in_use"
    assert client.delete(f"/sessions/{sid}", headers=bearer(ALICE)).status_code == 204
    assert client.delete("/maps/room", headers=bearer(ADMIN)).status_code == 204
