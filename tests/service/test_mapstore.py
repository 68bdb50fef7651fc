"""Map uploads are validated completely before anything is stored (issue 17).

Each test is one defect an outside tester found: a map the service accepted (or half
stored) and then could not serve. The files are built with a *valid* checksum, as an
attacker would, so the value checks are what refuses them.
"""

from __future__ import annotations

import gc
import io
import json
import tracemalloc
import weakref
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.mapstore import MapStore
from service.npzcheck import MapRejected, check_map_headers
from service.settings import Settings
from tests.service.helpers import TRACKED, map_arrays, map_file_bytes


@pytest.fixture()
def settings(tmp_path: Path) -> Settings:
    maps = tmp_path / "maps"
    maps.mkdir()
    (maps / "room.npz").write_bytes(map_file_bytes())
    return Settings(maps_dir=maps, sessions_dir=tmp_path / "sessions", runs_dir=tmp_path / "runs",
                    default_map=False, max_body_bytes=256 * 1024, max_map_bytes=4 << 20,
                    max_map_cells=200_000)


@pytest.fixture()
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as c:
        yield c


def upload(client: TestClient, data: bytes, map_id: str = "up", **params: Any) -> Any:
    return client.post("/maps", params={"map_id": map_id, **params}, content=data,
                       headers={"content-type": "application/octet-stream"})


def stored(settings: Settings) -> list[str]:
    return sorted(p.name for p in settings.maps_dir.iterdir())


def refused(client: TestClient, settings: Settings, arrays: dict[str, Any], field: str) -> None:
    before = stored(settings)
    r = upload(client, map_file_bytes(arrays))
    assert r.status_code == 422, r.text
    assert r.json()["field"] == field, r.text
    assert r.json()["allowed"]
    assert stored(settings) == before  # nothing stored, no temporary file left


def test_array_resolution_is_422_not_500(client: TestClient, settings: Settings) -> None:
    refused(client, settings, {**map_arrays(), "resolution_m": np.array([0.05, 0.05])},
            "resolution_m")


def test_json_string_provenance_refused_and_not_stored(client: TestClient,
                                                       settings: Settings) -> None:
    arrays = {**map_arrays(), "provenance": np.array(json.dumps("just a string"))}
    refused(client, settings, arrays, "provenance")
    assert client.get("/maps/up").status_code == 404
    ok = upload(client, map_file_bytes())  # the id is still free: no 409 on a re-upload
    assert ok.status_code == 201, ok.text
    assert client.get("/maps/up").status_code == 200


@pytest.mark.parametrize("origin", [(np.nan, 0.0), (1e300, 0.0), (0.0, -np.inf)])
def test_non_finite_or_huge_origin_refused(client: TestClient, settings: Settings,
                                           origin: tuple[float, float]) -> None:
    refused(client, settings, {**map_arrays(), "origin_m": np.array(origin)}, "origin_m")


@pytest.mark.parametrize("res", [1e-9, 0.0, -0.05, 1e6])
def test_resolution_out_of_range_refused(client: TestClient, settings: Settings,
                                         res: float) -> None:
    refused(client, settings, {**map_arrays(), "resolution_m": np.float64(res)}, "resolution_m")


@pytest.mark.parametrize("sonar", ["not json", json.dumps({"directions": 10**9}),
                                   json.dumps({"fs_hz": -1})])
def test_bad_sonar_refused(client: TestClient, settings: Settings, sonar: str) -> None:
    refused(client, settings, {**map_arrays(), "sonar": np.array(sonar)}, "sonar")


def test_complex_or_integer_g_refused(client: TestClient, settings: Settings) -> None:
    g = map_arrays()["G"]
    refused(client, settings, {**map_arrays(), "G": g.astype(np.complex128)}, "G")


def _bomb(cells: int) -> bytes:
    """A map file whose G header declares ``cells`` float64 zeros, deflated (~1000:1), with
    the other keys valid; built by streaming, never holding the array."""
    buf = io.BytesIO()
    rows = cells // 1000
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False,
                                                  "shape": (rows, 1000)})
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for key, value in {**map_arrays(), "format": np.array("omnisonar-map-2"),
                           "checksum": np.array("0" * 64)}.items():
            if key in ("G", "coverage"):
                continue
            with zf.open(f"{key}.npy", "w") as fh:
                np.lib.format.write_array(fh, np.asarray(value))
        with zf.open("G.npy", "w", force_zip64=True) as fh:
            fh.write(header.getvalue())
            left = rows * 1000 * 8
            zero = bytes(1 << 20)
            while left > 0:
                fh.write(zero[:left])
                left -= len(zero)
    return buf.getvalue()


def test_zip_bomb_refused_from_headers_with_bounded_memory(client: TestClient,
                                                           settings: Settings) -> None:
    data = _bomb(32_000_000)  # 256 MB of float64 zeros in < 0.5 MB
    assert len(data) < 512 * 1024
    tracemalloc.start()
    try:
        r = upload(client, data)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert r.status_code == 422 and r.json()["field"] == "G", r.text
    assert "cells" in r.json()["detail"]
    assert peak < 8 * len(data) + (4 << 20), peak  # the body and its copies, nothing inflated
    assert stored(client.app.state.settings) == ["room.npz"]  # type: ignore[attr-defined]


def test_oversize_map_refused_from_headers_before_decompressing() -> None:
    data = _bomb(2_000_000)
    with pytest.raises(MapRejected) as exc:
        check_map_headers(data, max_cells=1_000_000)
    assert exc.value.field == "G"
    members = check_map_headers(data, max_cells=2_000_000)  # the header alone says its size
    assert members["G"].shape == (2000, 1000)


def test_declared_size_must_match_header() -> None:
    data = bytearray(map_file_bytes())
    zf = zipfile.ZipFile(io.BytesIO(bytes(data)))
    assert check_map_headers(bytes(data), 10**6)["G"].file_size == zf.getinfo("G.npy").file_size
    with pytest.raises(MapRejected):
        check_map_headers(b"PK\x05\x06" + bytes(18), 10**6)  # an empty zip: no G
    with pytest.raises(MapRejected):
        check_map_headers(b"not a zip", 10**6)


def test_upload_error_never_names_a_server_path(client: TestClient, settings: Settings) -> None:
    good = map_file_bytes()
    flipped = good[:5000] + bytes([good[5000] ^ 0xFF]) + good[5001:]
    for data in (good[:-100], good[: len(good) // 2], flipped, b"garbage"):
        r = upload(client, data)
        assert r.status_code == 422
        assert str(settings.maps_dir.parent) not in r.text and ".upload" not in r.text, r.text


def test_orphan_temp_files_removed_at_start(settings: Settings) -> None:
    orphan = settings.maps_dir / ".room.x1y2.upload.npz"
    orphan.write_bytes(b"half an upload")
    half_written = settings.maps_dir / ".room.npz.abc123.tmp"
    half_written.write_bytes(b"half a map")
    with TestClient(create_app(settings)) as c:
        assert not orphan.exists() and not half_written.exists()
        assert [m["id"] for m in c.get("/maps").json()["maps"]] == ["room"]


def test_map_memory_released_when_no_session_uses_it(client: TestClient) -> None:
    r = client.post("/sessions", json={**TRACKED, "map_id": "room"})
    assert r.status_code == 201, r.text
    factory = client.app.state.sessions.factory  # type: ignore[attr-defined]
    assert len(factory._tables) == 1
    tables = weakref.ref(next(iter(factory._tables.values())))
    assert client.delete(f"/sessions/{r.json()['id']}").status_code == 204
    gc.collect()
    assert tables() is None and len(factory._tables) == 0
    maps: MapStore = client.app.state.maps  # type: ignore[attr-defined]
    assert len(maps._maps) == 0


def test_stored_map_info_reports_its_hash(client: TestClient, settings: Settings) -> None:
    import hashlib

    info = client.get("/maps/room").json()
    assert info["sha256"] == hashlib.sha256((settings.maps_dir / "room.npz").read_bytes()
                                            ).hexdigest()


def test_overwritten_map_never_changes_a_restored_session(settings: Settings) -> None:
    """A session pins its map's SHA-256; after an overwrite and a restart it is refused
    (409 naming the map, for its owner) instead of silently running on the other map."""
    with TestClient(create_app(settings)) as c:
        r = c.post("/sessions", json={**TRACKED, "map_id": "room"})
        assert r.status_code == 201, r.text
        sid, pinned = r.json()["id"], r.json()["map_sha256"]
        assert pinned == c.get("/maps/room").json()["sha256"]
        arrays = {**map_arrays(), "G": 2.0 * map_arrays()["G"]}  # another map, same id
        assert upload(c, map_file_bytes(arrays), "room", overwrite=True).status_code == 201
        # the live session keeps the map it started on
        assert c.get(f"/sessions/{sid}").json()["map_sha256"] == pinned
        assert c.get("/maps/room").json()["sha256"] != pinned
    with TestClient(create_app(settings)) as c:
        r = c.get(f"/sessions/{sid}")
        assert r.status_code == 409 and r.json()["error"] == "map_changed", r.text
        assert r.json()["field"] == "map_id" and "replaced" in r.json()["detail"]
        assert c.delete(f"/sessions/{sid}").status_code == 204
        assert c.get(f"/sessions/{sid}").status_code == 404
        assert not (settings.sessions_path / f"{sid}.npz").exists()


# -- DELETE /maps/{id} ---------------------------------------------------------------------
def test_delete_map(client: TestClient, settings: Settings) -> None:
    assert upload(client, map_file_bytes(), "gone").status_code == 201
    r = client.delete("/maps/gone")
    assert r.status_code == 204 and r.content == b""
    assert client.get("/maps/gone").status_code == 404
    assert "gone" not in [m["id"] for m in client.get("/maps").json()["maps"]]
    assert stored(settings) == ["room.npz"]  # no file left, not even a hidden one
    r = client.delete("/maps/gone")
    assert r.status_code == 404 and r.json()["field"] == "map_id"
    assert upload(client, map_file_bytes(), "gone").status_code == 201  # the id is free


def test_delete_map_refused_while_a_session_uses_it(client: TestClient,
                                                    settings: Settings) -> None:
    before = (settings.maps_dir / "room.npz").read_bytes()
    sid = client.post("/sessions", json=TRACKED).json()["id"]
    r = client.delete("/maps/room")
    assert r.status_code == 409, r.text
    assert r.json()["error"] == "in_use" and r.json()["field"] == "map_id"
    assert "1 live session" in r.json()["detail"]
    assert (settings.maps_dir / "room.npz").read_bytes() == before  # kept, unchanged
    assert stored(settings) == ["room.npz"]
    assert client.get(f"/sessions/{sid}").status_code == 200
    assert client.delete(f"/sessions/{sid}").status_code == 204
    assert client.delete("/maps/room").status_code == 204
    r = client.post("/sessions", json=TRACKED)  # as for any unknown map id
    assert r.status_code == 422 and r.json()["field"] == "map_id", r.text


def test_store_delete_never_clobbers_an_upload_made_meanwhile(tmp_path: Path) -> None:
    from service.mapstore import MapInUse

    maps = MapStore(tmp_path)
    maps.path("m").write_bytes(b"old")
    newer = b"uploaded while the delete asked who uses the map"

    def users() -> int:
        maps.path("m").write_bytes(newer)
        return 1

    with pytest.raises(MapInUse):
        maps.delete("m", users)
    assert maps.path("m").read_bytes() == newer
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


def test_delete_map_documented(client: TestClient) -> None:
    op = client.get("/openapi.json").json()["paths"]["/maps/{map_id}"]["delete"]
    assert {"204", "401", "403", "404", "409"} <= set(op["responses"])
