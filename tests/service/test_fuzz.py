"""Property test: no client input makes the service answer 5xx.

Complements ``test_service_schemathesis.py`` (inputs generated from the OpenAPI schema) with
what a schema cannot describe: every endpoint gets random paths, query parameters, headers,
content types and bodies (wrong types, out-of-range and non-finite numbers, unknown fields,
raw binary blocks, garbage and oversize bodies), and every answer must be < 500 with a JSON
error body for 4xx. Bounded: ~40 examples per endpoint.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any
from urllib.parse import quote

import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mapping.files import write_map
from mapping.signal import SonarConfig
from service.app import create_app
from service.settings import Settings
from tests.service.helpers import TRACKED, raster_map

B = SonarConfig().block_samples
LIMIT = 256 * 1024

scalars = (st.none() | st.booleans() | st.integers(-2**70, 2**70)
           | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=12))
json_values = st.recursive(scalars, lambda k: st.lists(k, max_size=4)
                           | st.dictionaries(st.text(max_size=8), k, max_size=4), max_leaves=10)
query_values = (st.integers(-2**64, 2**64).map(str) | st.floats().map(str)
                | st.sampled_from(["", "nan", "inf", "-0", "1e999", "0x10", "float32", "int16",
                                   "true"]) | st.text(max_size=10))
ids = (st.sampled_from(["room", "default", "nope", "", "..", "a" * 200, "%00", "x/y"])
       | st.text(max_size=20)).map(lambda s: quote(s, safe=""))  # as a client would send it


def bodies() -> st.SearchStrategy[bytes]:
    def block(kind: int, seed: int) -> bytes:
        rng = np.random.default_rng(seed)
        if kind == 0:
            return (0.01 * rng.standard_normal(B)).astype("<f4").tobytes()
        if kind == 1:
            return rng.integers(-3000, 3000, B).astype("<i2").tobytes()
        if kind == 2:
            return rng.bytes(B * 4)  # random bit patterns: NaN, inf, huge
        return b"\0" * (LIMIT + 1 + seed % 1000)

    return (st.binary(max_size=64) | st.builds(block, st.integers(0, 3), st.integers(0, 2**16))
            | json_values.map(lambda v: json.dumps(v).encode()))


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    root = tmp_path_factory.mktemp("fuzz")
    write_map(root / "maps" / "room.npz", raster_map())
    cfg = Settings(maps_dir=root / "maps", sessions_dir=root / "sessions", runs_dir=root / "runs",
                   default_map=False, max_sessions=8, max_particles=500, max_body_bytes=LIMIT,
                   max_map_bytes=LIMIT, session_idle_s=3600)
    with TestClient(create_app(cfg), raise_server_exceptions=False) as c:
        yield c


def check(r: Any) -> None:
    assert r.status_code < 500, (r.request.method, r.request.url, r.status_code, r.text[:300])
    if r.status_code >= 400:
        body = r.json()
        assert body["error"] and isinstance(body["detail"], str)


def post_json(client: TestClient, url: str, obj: Any) -> Any:
    """POST any JSON-ish value, NaN and Infinity tokens included (httpx's json= refuses)."""
    return client.post(url, content=json.dumps(obj).encode(),
                       headers={"content-type": "application/json"})


def live_session(client: TestClient) -> str:
    r = client.post("/sessions", json={**TRACKED, "particles": 100})
    if r.status_code == 429:  # cap reached by earlier examples: free them
        for sid in client.app.state.sessions.ids():  # type: ignore[attr-defined]
            client.delete(f"/sessions/{sid}")
        r = client.post("/sessions", json={**TRACKED, "particles": 100})
    assert r.status_code == 201, r.text
    return str(r.json()["id"])


FUZZ = settings(max_examples=40, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


@FUZZ
@given(body=json_values, extra=st.dictionaries(st.sampled_from(
    ["map_id", "filter", "particles", "seed", "initial_pose", "initial_covariance", "global"]),
    json_values, max_size=4))
def test_fuzz_create_session(client: TestClient, body: Any, extra: dict[str, Any]) -> None:
    check(post_json(client, "/sessions", body))
    r = post_json(client, "/sessions", {**TRACKED, "particles": 100, **extra})
    check(r)
    if r.status_code == 201:
        check(client.delete(f"/sessions/{r.json()['id']}"))


@FUZZ
@given(params=st.dictionaries(st.sampled_from(["seq", "fs_hz", "speed_m_s", "yaw_rate_rad_s",
                                               "encoding", "other"]), query_values, max_size=3),
       headers=st.dictionaries(st.sampled_from(["x-omnisonar-seq", "x-omnisonar-fs-hz",
                                                "x-forwarded-for", "accept"]),
                               st.text("0123456789.-eainf", max_size=8), max_size=3),
       ctype=st.sampled_from(["application/octet-stream", "application/json", "text/plain", "",
                              "application/json; charset=utf-8", "multipart/form-data"]),
       body=bodies())
def test_fuzz_blocks(client: TestClient, params: dict[str, str], headers: dict[str, str],
                     ctype: str, body: bytes) -> None:
    sid = live_session(client)
    before = client.get(f"/sessions/{sid}").json()
    near_valid = {"seq": "0", "fs_hz": "40000", "speed_m_s": "0.2", **params}  # mostly one bad
    r = client.post(f"/sessions/{sid}/blocks", params=near_valid, content=body,
                    headers={**headers, "content-type": ctype})
    check(r)
    after = client.get(f"/sessions/{sid}").json()
    if r.status_code >= 400:
        for k in ("expires_in_s", "last_active_at"):
            before.pop(k), after.pop(k)
        assert after == before
    check(client.delete(f"/sessions/{sid}"))


@FUZZ
@given(sid=ids, mx=query_values, method=st.sampled_from(["GET", "DELETE", "POST", "PUT"]),
       sub=st.sampled_from(["", "/particles", "/global", "/blocks", "/x"]))
def test_fuzz_session_paths(client: TestClient, sid: str, mx: str, method: str, sub: str) -> None:
    check(client.request(method, f"/sessions/{sid}{sub}", params={"max": mx}))


@FUZZ
@given(map_id=ids, overwrite=query_values, body=bodies(), build=json_values,
       job=ids)
def test_fuzz_maps(client: TestClient, map_id: str, overwrite: str, body: bytes, build: Any,
                   job: str) -> None:
    check(client.get(f"/maps/{map_id}"))
    check(client.get(f"/maps/{map_id}/image.png"))
    check(client.post("/maps", params={"map_id": map_id, "overwrite": overwrite}, content=body))
    check(post_json(client, "/maps/build", build))
    check(post_json(client, "/maps/build", {"runs": [map_id], "map_id": map_id}))
    check(client.get(f"/jobs/{job}"))
    check(client.get("/maps"))
