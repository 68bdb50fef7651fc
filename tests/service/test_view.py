"""The live view's server side: the publish hook, the event stream, the rendered events and
the page's routes (the browser side: ``test_view_browser.py``)."""

from __future__ import annotations

import asyncio
import base64
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from mapping.heatmap import HeatMap
from mapping.signal import SonarConfig
from service.app import create_app
from service.live import Broadcaster
from service.routers.view import (
    MAX_PARTICLES,
    Frame,
    _stream,
    heatmap_json,
    state_json,
    take_frame,
)
from service.sessions import BlockInput, FilterSpec, Session, SessionStore
from service.settings import Settings
from tests.service.doubles import OdometryFactory

CFG = SonarConfig()
SPEC = FilterSpec(kind="pf", particles=1000, seed=3, initial_pose=(1.0, 2.0, 0.0))


def _block(seq: int) -> BlockInput:
    return BlockInput(seq=seq, samples=np.zeros(CFG.block_samples), speed_m_s=0.2,
                      yaw_rate_rad_s=0.0)


def _store(tmp_path: Path) -> SessionStore:
    return SessionStore(tmp_path / "sessions", 4, 60.0, OdometryFactory())  # type: ignore[arg-type]


# ---- the publish hook ---------------------------------------------------------------------
def test_broadcaster_subscribe_publish_close() -> None:
    b = Broadcaster()
    got: list[Any] = []
    assert not b.watched("s")
    stop = b.subscribe("s", got.append)
    b.subscribe("s", lambda _: (_ for _ in ()).throw(RuntimeError("broken watcher")))
    assert b.watched("s") and b.count("s") == 2
    b.publish("s", 1)  # the broken watcher does not keep the item from the other one
    b.publish("other", 2)
    stop()
    assert b.count("s") == 1
    b.close("s")
    assert got == [1] and not b.watched("s")


def test_store_publishes_committed_blocks_only_to_watchers(tmp_path: Path) -> None:
    store = _store(tmp_path)
    s = store.create("m", SPEC)
    store.update(s.id, _block(0))  # nobody watches: nothing to call
    seen: list[Session | None] = []
    stop = store.live.subscribe(s.id, seen.append)
    store.update(s.id, _block(1))
    with pytest.raises(ValueError):  # a rejected block is not published
        store.update(s.id, BlockInput(seq=2, samples=np.full(CFG.block_samples, 1e6),
                                      speed_m_s=0.2, yaw_rate_rad_s=0.0))
    store.reinit_global(s.id)
    stop()
    store.update(s.id, _block(3))
    assert seen == [s, s]
    store.live.subscribe(s.id, seen.append)
    store.delete(s.id)
    assert seen[-1] is None  # the session ended


# ---- rendering ----------------------------------------------------------------------------
def _heatmap() -> HeatMap:
    h = np.zeros((30, 4092))
    h[3, 1000] = 4.0
    h[20, 10] = 1.0
    ranges = np.arange(4092, dtype=np.float64) * (CFG.sound_speed_m_s / (2 * CFG.fs_hz))
    return HeatMap(H=h, angles_rad=np.linspace(0, math.pi, 30), ranges_m=ranges,
                   speed_m_s=0.2, direction_observable=True)


def test_heatmap_json_pools_and_scales() -> None:
    hm = _heatmap()
    out = heatmap_json(hm, columns=256)
    data = np.frombuffer(base64.b64decode(out["data_b64"]), np.uint8)
    img = data.reshape(out["rows"], out["cols"])
    assert out["rows"] == 30 and out["cols"] == 4092 // (4092 // 256)
    assert img.max() == 255 and img[3].argmax() == 1000 // (4092 // 256)
    assert img[20, 0] == round(255 * math.sqrt(1 / 4))  # square-root scale
    near = heatmap_json(hm, max_range_m=2.0)
    assert near["range_max_m"] <= 2.0
    assert heatmap_json(HeatMap(np.zeros((2, 8)), np.zeros(2), np.arange(8.0), 0.0, False))[
        "data_b64"] == base64.b64encode(bytes(16)).decode()  # all zero: no division by 0


def test_state_json_of_a_session(tmp_path: Path) -> None:
    store = _store(tmp_path)
    s = store.create("m", SPEC)
    before = state_json(s.id, take_frame(s))
    assert before["estimate"] is None and before["seq"] is None
    assert len(before["particles"]["x"]) <= MAX_PARTICLES
    store.update(s.id, _block(0))
    frame = take_frame(s)
    out = json.loads(json.dumps(state_json(s.id, frame)))  # JSON all the way
    est = out["estimate"]
    assert out["seq"] == 0 and out["n_updates"] == 1
    assert est["status"] in ("converged", "uncertain", "lost")
    assert -math.pi < est["yaw"] <= math.pi
    assert np.allclose(est["cov_xy"], np.asarray(s.estimate.cov)[:2, :2], atol=1e-8)  # type: ignore[union-attr]
    assert max(out["particles"]["w"]) == 1.0
    frame_hm = Frame(**{**frame.__dict__, "heatmap": _heatmap()})
    assert state_json(s.id, frame_hm)["heatmap"]["rows"] == 30


# ---- the event stream ---------------------------------------------------------------------
def _events(chunks: list[bytes]) -> list[tuple[str, Any]]:
    out = []
    for chunk in chunks:
        text = chunk.decode()
        if text.startswith(":"):
            continue
        event = text.split("\n")[0].removeprefix("event: ")
        out.append((event, json.loads(text.split("\n")[1].removeprefix("data: "))))
    return out


def test_stream_sends_map_state_per_block_and_end(tmp_path: Path) -> None:
    store = _store(tmp_path)
    s = store.create("m", SPEC)
    first = {"extent_m": [0.0, 4.0, 0.0, 3.0], "walls_m": []}

    async def watch() -> list[bytes]:
        got: list[bytes] = []
        stream = _stream(store, s, first)
        got.append(await anext(stream))  # map
        got.append(await anext(stream))  # state now
        assert store.live.watched(s.id)
        await asyncio.to_thread(store.update, s.id, _block(0))
        got.append(await anext(stream))
        await asyncio.to_thread(store.update, s.id, _block(1))
        got.append(await anext(stream))
        await asyncio.to_thread(store.delete, s.id)
        got.extend([chunk async for chunk in stream])
        return got

    events = _events(asyncio.run(watch()))
    assert [e for e, _ in events] == ["map", "state", "state", "state", "end"]
    assert [d["seq"] for e, d in events if e == "state"] == [None, 0, 1]
    assert not store.live.watched(s.id)  # the stream unsubscribed when it ended


def test_stream_coalesces_to_the_latest_state(tmp_path: Path) -> None:
    store = _store(tmp_path)
    s = store.create("m", SPEC)

    async def watch() -> tuple[list[bytes], bool]:
        stream = _stream(store, s, {"extent_m": [0.0, 1.0, 0.0, 1.0], "walls_m": []})
        got = [await anext(stream), await anext(stream)]
        for k in range(3):  # three blocks before the page reads: it sees the last one
            await asyncio.to_thread(store.update, s.id, _block(k))
        await asyncio.sleep(0.05)
        got.append(await anext(stream))
        await stream.aclose()  # the page went away
        return got, store.live.watched(s.id)

    chunks, still_watched = asyncio.run(watch())
    assert _events(chunks)[-1][1]["seq"] == 2
    assert not still_watched


# ---- routes -------------------------------------------------------------------------------
@pytest.fixture()
def client(tmp_path: Path) -> Any:
    cfg = Settings(maps_dir=tmp_path / "maps", sessions_dir=tmp_path / "s", default_map=False)
    with TestClient(create_app(cfg, factory=lambda _: OdometryFactory())) as c:  # type: ignore[arg-type, return-value]
        yield c


def test_page_and_assets_are_served_locally(client: TestClient) -> None:
    page = client.get("/sessions/abc/view")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "../../view/view.js" in page.text and "http" not in page.text.split("<body")[1]
    js = client.get("/view/view.js")
    assert js.status_code == 200 and "text/javascript" in js.headers["content-type"]
    assert "EventSource" not in js.text and "fetch(\"events\"" in js.text
    assert client.get("/view/view.css").status_code == 200
    assert client.get("/view/secrets.txt").status_code == 404
    paths = client.get("/openapi.json").json()["paths"]
    assert not any(p.endswith(("/view", "/events")) or p.startswith("/view") for p in paths)


def test_events_of_an_unknown_session_is_404(client: TestClient) -> None:
    r = client.get("/sessions/nope/events")
    assert r.status_code == 404 and r.json()["error"] == "not_found"
