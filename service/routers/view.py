"""The live view of a session: an HTML page and the server-sent events that drive it.

``GET /sessions/{id}/view`` serves a static page (``service/static/``: plain HTML, canvas and
JavaScript, nothing fetched from elsewhere). The page reads ``GET /sessions/{id}/events``
(``text/event-stream``): first one ``map`` event (extent, walls, G as a PNG data URL), then a
``state`` event now and after every committed block (pose, covariance, status, fit,
particles, the last heat map), ``end`` when the session is deleted or expires, and a comment
line every :data:`HEARTBEAT_S` seconds so proxies keep the connection open.

The page itself carries no data and needs no key; the events need the session owner's key
(the page sends it as ``Authorization: Bearer``, read from the URL fragment ``#key=...``,
which browsers never send to the server). Both routes stay out of the OpenAPI document:
they serve browsers, not generated clients.

The block path pays for a watcher only while someone watches (:mod:`service.live`): the
watcher copies a few hundred particles and keeps a reference to the heat map, under the
session's lock, and hands them to the event loop; a slow page sees the latest state only.
"""

from __future__ import annotations

import asyncio
import base64
import json
import math
from collections.abc import AsyncGenerator
from dataclasses import dataclass
from importlib import resources
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Depends, Request
from fastapi.responses import HTMLResponse, Response, StreamingResponse
from numpy.typing import NDArray

from localization.estimate import PoseEstimate
from mapping.angles import wrap_angle
from mapping.heatmap import HeatMap
from service.auth import Caller
from service.deps import get_maps, get_sessions
from service.errors import ClientError
from service.mapstore import MapStore
from service.routers.sessions import SessionIdPath, owned
from service.sessions import Session, SessionStore

router = APIRouter(tags=["view"])

#: Seconds between keep-alive comments on an idle event stream.
HEARTBEAT_S = 15.0
#: Most particles a ``state`` event carries (every k-th, in storage order).
MAX_PARTICLES = 400
#: Heat-map columns (range bins, max-pooled) a ``state`` event carries.
HEATMAP_COLUMNS = 256
#: Files the page loads from ``service/static/``.
ASSETS = {"view.js": "text/javascript", "view.css": "text/css"}


# ---- what a watcher takes from a session (under its lock, in the update's thread) ---------
@dataclass(frozen=True)
class Frame:
    """One published state of a session: taken quickly, rendered later off the block path."""

    seq: int | None
    n_updates: int
    processing_ms: float
    estimate: PoseEstimate | None
    particles: tuple[NDArray[np.float64], NDArray[np.float64]] | None  # poses (k, 3), weights
    heatmap: HeatMap | None


def take_frame(session: Session) -> Frame:
    """The session's state now, with at most :data:`MAX_PARTICLES` particles (copies)."""
    got = session.tracker.particles()
    parts = None
    if got is not None:
        poses, weights = got
        step = max(1, math.ceil(poses.shape[0] / MAX_PARTICLES))
        parts = (poses[::step].copy(), weights[::step].copy())
    return Frame(seq=session.last_seq, n_updates=session.n_updates,
                 processing_ms=session.processing_ms, estimate=session.estimate,
                 particles=parts, heatmap=getattr(session.tracker, "last_heatmap", None))


# ---- rendering (pure functions: frame -> JSON-able dict) ----------------------------------
def _r(x: float, digits: int = 4) -> float | None:
    return None if not math.isfinite(x) else round(float(x), digits)


def heatmap_json(hm: HeatMap, max_range_m: float = math.inf,
                 columns: int = HEATMAP_COLUMNS) -> dict[str, Any]:
    """H up to ``max_range_m``, max-pooled to ``columns`` range bins, as 0..255 of the square
    root of H over its peak (weak echoes stay visible), base64 rows (one per direction)."""
    keep = max(1, int(np.searchsorted(hm.ranges_m, max_range_m, side="right")))
    h = np.asarray(hm.H, dtype=np.float64)[:, :keep]
    n_dirs, n_tau = h.shape
    per = max(1, n_tau // columns)
    pooled = h[:, : per * (n_tau // per)].reshape(n_dirs, -1, per).max(axis=2)
    peak = float(pooled.max()) if pooled.size else 0.0
    scaled = np.zeros(pooled.shape, np.uint8) if not peak > 0 else \
        np.clip(np.rint(255 * np.sqrt(np.maximum(pooled, 0) / peak)), 0, 255).astype(np.uint8)
    return {
        "rows": int(scaled.shape[0]), "cols": int(scaled.shape[1]),
        "angle_min_deg": _r(math.degrees(float(hm.angles_rad[0])), 2),
        "angle_max_deg": _r(math.degrees(float(hm.angles_rad[-1])), 2),
        "range_max_m": _r(float(hm.ranges_m[per * (n_tau // per) - 1]), 3),
        "speed_m_s": _r(float(hm.speed_m_s)),
        "direction_observable": bool(hm.direction_observable),
        "data_b64": base64.b64encode(scaled.tobytes()).decode("ascii"),
    }


def state_json(session_id: str, frame: Frame, max_range_m: float = math.inf
               ) -> dict[str, Any]:
    """The ``state`` event of one frame (poses in the map frame, yaw in (-pi, pi]; the heat
    map up to ``max_range_m``, e.g. the map's diagonal)."""
    est = frame.estimate
    out: dict[str, Any] = {"session_id": session_id, "seq": frame.seq,
                           "n_updates": frame.n_updates, "estimate": None, "particles": None,
                           "heatmap": None}
    if est is not None:
        pose = np.asarray(est.pose, dtype=np.float64)
        out["estimate"] = {
            "x": _r(pose[0]), "y": _r(pose[1]), "yaw": _r(float(wrap_angle(pose[2]))),
            "cov_xy": [[_r(v, 8) for v in row] for row in np.asarray(est.cov)[:2, :2]],
            "std_yaw_deg": _r(math.degrees(math.sqrt(max(float(est.cov[2][2]), 0.0))), 2),
            "status": str(est.status), "converged": bool(est.converged),
            "fit": None if math.isnan(est.fit) else _r(est.fit),
            "ess": _r(est.ess, 1), "n_modes": len(est.modes),
            "processing_ms": _r(frame.processing_ms, 2),
        }
    if frame.particles is not None:
        poses, weights = frame.particles
        out["particles"] = {"x": np.round(poses[:, 0], 3).tolist(),
                            "y": np.round(poses[:, 1], 3).tolist(),
                            "w": (weights / max(float(weights.max()), 1e-300)).round(3).tolist()}
    if frame.heatmap is not None:
        out["heatmap"] = heatmap_json(frame.heatmap, max_range_m)
    return out


def map_json(maps: MapStore, session: Session) -> dict[str, Any]:
    """The ``map`` event: extent, walls and G (a PNG data URL, one pixel per cell)."""
    wallmap, digest = maps.load(session.map_id)
    ny, nx = np.asarray(wallmap.G).shape
    res = float(wallmap.resolution_m)
    x0, y0 = (float(v) - res / 2 for v in wallmap.origin_m)  # lower-left corner of cell 0
    png = base64.b64encode(maps.png(session.map_id)).decode("ascii")
    return {"map_id": session.map_id, "sha256": digest,
            "pinned": session.spec.map_sha256 in (None, digest),
            "extent_m": [x0, x0 + nx * res, y0, y0 + ny * res], "resolution_m": res,
            "walls_m": np.round(np.asarray(wallmap.walls_m, dtype=np.float64), 4).tolist(),
            "g_png": f"data:image/png;base64,{png}"}


def sse(event: str, data: dict[str, Any]) -> bytes:
    """One server-sent event (JSON on a single ``data:`` line)."""
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n".encode()


# ---- routes -------------------------------------------------------------------------------
def _asset(name: str) -> bytes:
    return resources.files("service").joinpath("static", name).read_bytes()


@router.get("/sessions/{session_id}/view", response_class=HTMLResponse,
            include_in_schema=False)
def view_page(session_id: SessionIdPath) -> HTMLResponse:
    """The live view (static: its data comes from the events, which need the key)."""
    return HTMLResponse(_asset("view.html"), headers={"Cache-Control": "no-cache"})


@router.get("/view/{name}", include_in_schema=False)
def view_asset(name: str) -> Response:
    """The page's script and style sheet."""
    if name not in ASSETS:
        raise ClientError(404, "not_found", f"no asset {name!r}", "name", ", ".join(ASSETS))
    return Response(_asset(name), media_type=ASSETS[name],
                    headers={"Cache-Control": "no-cache"})


@router.get("/sessions/{session_id}/events", include_in_schema=False)
async def view_events(
    session_id: SessionIdPath, request: Request, who: Caller,
    store: Annotated[SessionStore, Depends(get_sessions)],
    maps: Annotated[MapStore, Depends(get_maps)],
) -> StreamingResponse:
    """``text/event-stream`` of the session: ``map``, then ``state`` per committed block."""
    session = owned(store, session_id, who)
    first = await asyncio.to_thread(map_json, maps, session)
    return StreamingResponse(
        _stream(store, session, first), media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


async def _stream(store: SessionStore, session: Session,
                  first: dict[str, Any]) -> AsyncGenerator[bytes, None]:
    loop = asyncio.get_running_loop()
    x0, x1, y0, y1 = first["extent_m"]
    reach_m = math.hypot(x1 - x0, y1 - y0)  # no echo in the map comes from farther
    latest: list[Frame | None] = []
    wake = asyncio.Event()

    def deliver(item: Frame | None) -> None:  # on the event loop
        latest[:] = [item]
        wake.set()

    def watcher(s: Session | None) -> None:  # in the update's thread, under the lock
        frame = None if s is None else take_frame(s)
        loop.call_soon_threadsafe(deliver, frame)

    with session.lock:
        unsubscribe = store.live.subscribe(session.id, watcher)
        _keep_heatmap(session, True)
        now = take_frame(session)
    try:
        yield sse("map", first)
        yield sse("state", state_json(session.id, now, reach_m))
        while True:
            try:
                await asyncio.wait_for(wake.wait(), HEARTBEAT_S)
            except TimeoutError:
                yield b": keep-alive\n\n"
                continue
            wake.clear()
            if not latest:
                continue
            frame = latest.pop()
            if frame is None:
                yield sse("end", {"session_id": session.id})
                return
            yield sse("state", state_json(session.id, frame, reach_m))
    finally:
        unsubscribe()
        if store.live.count(session.id) == 0:
            with session.lock:
                _keep_heatmap(session, False)


def _keep_heatmap(session: Session, keep: bool) -> None:
    """Ask the tracker to keep its last heat map while someone watches (if it can)."""
    if hasattr(session.tracker, "keep_heatmap"):
        setattr(session.tracker, "keep_heatmap", keep)  # noqa: B010 - not in Tracker
        if not keep:
            setattr(session.tracker, "last_heatmap", None)  # noqa: B010
