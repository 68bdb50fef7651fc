"""Admission of concurrent work (service/quotas.py): the map-upload gate (issue 17).

An upload holds its body and, while validated, its arrays in memory; the gate admits
``OMNISONAR_MAX_UPLOADS`` at once and one per key, refusing at once (503 / 429 with
Retry-After) instead of queueing.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.auth import ANONYMOUS
from service.quotas import Busy, Gate, OverQuota
from service.settings import Settings
from tests.service.helpers import map_file_bytes


def test_gate_caps_total_and_per_owner_and_releases() -> None:
    gate = Gate("uploads", total=2, per_owner=1)
    with gate.enter("a"):
        with pytest.raises(OverQuota), gate.enter("a"):
            pass
        with gate.enter("b"), pytest.raises(Busy), gate.enter("c"):
            pass
    with gate.enter("a"), gate.enter("c"):  # everything released, also after a refusal
        pass
    with pytest.raises(RuntimeError), gate.enter("a"):
        raise RuntimeError("the upload failed")
    with gate.enter("a"):  # released after an exception too
        pass


@pytest.fixture()
def client(tmp_path: Path) -> Iterator[TestClient]:
    maps = tmp_path / "maps"
    maps.mkdir()
    cfg = Settings(maps_dir=maps, sessions_dir=tmp_path / "sessions", default_map=False,
                   max_uploads=1)
    with TestClient(create_app(cfg)) as c:
        yield c


def _upload(client: TestClient, map_id: str) -> httpx.Response:
    return client.post("/maps", params={"map_id": map_id}, content=map_file_bytes(),
                       headers={"content-type": "application/octet-stream"})


def test_upload_refused_while_the_server_gate_is_full(client: TestClient) -> None:
    gate: Gate = client.app.state.uploads  # type: ignore[attr-defined]
    with gate.enter("another key"):  # an upload in progress elsewhere
        r = _upload(client, "m1")
        assert r.status_code == 503 and r.headers["retry-after"], r.text
        assert r.json()["error"] == "busy"
    assert client.get("/maps/m1").status_code == 404
    assert _upload(client, "m1").status_code == 201


def test_one_upload_per_key_at_once(tmp_path: Path) -> None:
    maps = tmp_path / "maps"
    maps.mkdir()
    cfg = Settings(maps_dir=maps, sessions_dir=tmp_path / "sessions", default_map=False,
                   max_uploads=4)
    with TestClient(create_app(cfg)) as c:
        gate: Gate = c.app.state.uploads  # type: ignore[attr-defined]
        with gate.enter(ANONYMOUS):  # this client's own upload still in progress
            r = _upload(c, "m2")
            assert r.status_code == 429 and r.headers["retry-after"], r.text
        assert _upload(c, "m2").status_code == 201
