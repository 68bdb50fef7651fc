"""``/sessions``: live localization sessions and the block stream that drives them.

Filter updates are CPU work: handlers are plain ``def`` (FastAPI's threadpool) or, where the
raw body must be read first, ``async`` handlers that hand the update to the threadpool
explicitly. One lock per session serializes its updates; different sessions run in parallel.

Every route needs a key (:mod:`service.auth`); a session answers only the key that created
it (and admin keys): any other key gets 404, as for an id that does not exist.

Sequence numbers: the first block of a session may carry any ``seq`` in
``0 .. OMNISONAR_MAX_SEQ_GAP``, each later one ``last + 1 .. last + OMNISONAR_MAX_SEQ_GAP``
(a gap is lost blocks: the motion step spans it). Anything else is 409 naming the accepted
range and changes nothing, so no single request can push ``seq`` out of a client's reach.
"""

from __future__ import annotations

import base64
import binascii
import math
import secrets
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Depends, Path, Query, Request, Response
from numpy.typing import NDArray
from pydantic import Field, ValidationError
from starlette.concurrency import run_in_threadpool

from localization.estimate import PoseEstimate
from mapping.angles import wrap_angle
from mapping.signal import SonarConfig
from service.auth import Caller, Principal
from service.deps import get_app_settings, get_maps, get_sessions
from service.errors import ClientError, validation_response
from service.mapstore import MapStore
from service.schemas import (
    FIELD_RANGES,
    BlockJSON,
    BlockQuery,
    ErrorBody,
    Estimate,
    Mode,
    Particles,
    PlainInt,
    Pose2D,
    SessionCreate,
    SessionInfo,
)
from service.sessions import (
    BlockInput,
    FilterSpec,
    Session,
    SessionNotFound,
    SessionRefused,
    SessionStore,
)
from service.settings import Settings

router = APIRouter(tags=["sessions"])

SessionIdPath = Annotated[str, Path(max_length=64, description="session id")]
Store = Annotated[SessionStore, Depends(get_sessions)]
_E = {"model": ErrorBody}
#: Answers of every route on one session: no key (401), not this key's or no such (404), a
#: session whose map was replaced while the server was down (409).
_ONE: dict[int | str, dict[str, Any]] = {401: _E, 404: _E, 409: _E}
AppSettings = Annotated[Settings, Depends(get_app_settings)]


def owned(store: SessionStore, session_id: str, who: Principal) -> Session:
    """The session ``session_id`` if ``who`` may use it; 404 otherwise (ids of other keys'
    sessions are not disclosed), 409 to its owner for a session refused at restart."""
    try:
        s = store.get(session_id)
    except SessionRefused as exc:
        if not who.may_use(exc.owner):
            raise SessionNotFound(session_id) from None
        raise
    if not who.may_use(s.owner):
        raise SessionNotFound(session_id)
    return s


# ---- the one conversion of the core's estimate --------------------------------------------
def estimate_model(session_id: str, seq: int | None, est: PoseEstimate,
                   processing_ms: float) -> Estimate:
    """``localization``'s :class:`PoseEstimate` -> response model (yaw wrapped to (-pi, pi];
    the 3x3 covariance also laid out as ROS's row-major 6x6, z/roll/pitch zero, as AMCL)."""

    def pose(p: NDArray[np.float64]) -> Pose2D:
        return Pose2D.model_construct(x=float(p[0]), y=float(p[1]), yaw=float(wrap_angle(p[2])))

    cov = np.asarray(est.cov, dtype=np.float64)
    ros = np.zeros((6, 6))
    ros[np.ix_([0, 1, 5], [0, 1, 5])] = cov
    return Estimate(
        session_id=session_id, seq=seq, pose=pose(est.pose), covariance=cov.tolist(),
        covariance_ros=ros.ravel().tolist(),
        covariance_all=np.asarray(est.cov_all, dtype=np.float64).tolist(),
        modes=[Mode(pose=pose(m.mean), weight=float(m.weight)) for m in est.modes],
        ess=float(est.ess), converged=bool(est.converged),
        direction_observable=bool(est.direction_observable),
        likelihood_scale=float(est.likelihood_scale), status=est.status,  # type: ignore[arg-type]
        fit=None if math.isnan(est.fit) else float(est.fit), covered=bool(est.covered),
        refined=bool(est.refined), reckoned=bool(est.reckoned), reason=str(est.reason),
        processing_ms=float(processing_ms),
    )


def session_info(store: SessionStore, s: Session) -> SessionInfo:
    return SessionInfo(
        id=s.id, map_id=s.map_id, map_sha256=s.spec.map_sha256,
        filter=s.spec.kind,  # type: ignore[arg-type]
        particles=s.spec.particles, seed=s.spec.seed, beta=s.spec.beta,
        sound_speed_m_s=s.spec.sound_speed_m_s, sonar_height_m=s.spec.sonar_height_m,
        ceiling_height_m=s.spec.ceiling_height_m,
        open_map=s.spec.open_map,  # type: ignore[arg-type]
        created_at=s.created_at,
        last_active_at=s.last_active_at, expires_in_s=store.expires_in_s(s),
        last_seq=s.last_seq, n_updates=s.n_updates,
        estimate=None if s.estimate is None else estimate_model(s.id, s.last_seq, s.estimate,
                                                                s.processing_ms),
    )


# ---- session lifecycle --------------------------------------------------------------------
@router.post("/sessions", status_code=201, response_model=SessionInfo,
             responses={401: _E, 413: _E, 422: _E, 429: _E, 503: _E})
def create_session(
    req: SessionCreate, response: Response, store: Store, who: Caller,
    maps: Annotated[MapStore, Depends(get_maps)], cfg: AppSettings,
) -> SessionInfo:
    """Start a filter on a map, from a pose with covariance or globally.

    The session is pinned to the map's content (``map_sha256``): overwriting the map later
    never changes it. An initial pose must lie on the map (422 naming the coordinate). At
    most ``OMNISONAR_MAX_SESSIONS_PER_KEY`` sessions per key (429 beyond).
    """
    if req.particles > cfg.max_particles:
        raise ClientError(422, "validation", f"particles {req.particles} over the cap",
                          "particles", f"10 <= particles <= {cfg.max_particles}")
    _require_map(maps, req.map_id)
    sha = maps.digest(req.map_id)
    if req.initial_pose is not None:
        _check_on_map(req.initial_pose, maps.info(req.map_id)["extent_m"])
    seed = req.seed if req.seed is not None else secrets.randbits(63)
    pose = None if req.initial_pose is None else (
        req.initial_pose.x, req.initial_pose.y, float(wrap_angle(req.initial_pose.yaw)))
    cov = req.initial_covariance
    spec = FilterSpec(kind=req.filter, particles=req.particles, seed=seed, initial_pose=pose,
                      initial_covariance=None if cov is None else tuple(tuple(r) for r in cov),
                      beta=req.beta, map_sha256=sha, sound_speed_m_s=req.sound_speed_m_s,
                      sonar_height_m=req.sonar_height_m, ceiling_height_m=req.ceiling_height_m,
                      open_map=req.open_map)
    # InvalidSpec (422) names a field the filter refuses
    s = store.create(req.map_id, spec, owner=who.name, max_per_owner=cfg.max_sessions_per_key)
    response.headers["Location"] = f"/sessions/{s.id}"
    return session_info(store, s)


def _require_map(maps: MapStore, map_id: str) -> None:
    from service.routers.maps import DEFAULT_MAP_ID

    if maps.exists(map_id):
        return
    if map_id == DEFAULT_MAP_ID:
        raise ClientError(503, "unavailable", "the default map is still being built",
                          "map_id", None, headers={"Retry-After": "30"})
    raise ClientError(422, "validation", f"no map {map_id!r}", "map_id",
                      "the id of a stored map (GET /maps)")


def _check_on_map(pose: Pose2D, extent_m: tuple[float, float, float, float]) -> None:
    """422 naming ``initial_pose.x`` / ``.y`` when the pose lies outside the map."""
    xmin, xmax, ymin, ymax = extent_m
    for name, v, lo, hi in (("x", pose.x, xmin, xmax), ("y", pose.y, ymin, ymax)):
        if not lo <= v <= hi:
            raise ClientError(422, "validation", f"initial_pose.{name} {v:g} m is off the map",
                              f"initial_pose.{name}", f"{lo:.3f} <= {name} <= {hi:.3f} m (the "
                              "map's extent)")


@router.get("/sessions/{session_id}", response_model=SessionInfo, responses=_ONE)
def get_session(session_id: SessionIdPath, store: Store, who: Caller) -> SessionInfo:
    """The session and its last estimate."""
    s = owned(store, session_id, who)
    with s.lock:
        store.touch(s)
        return session_info(store, s)


@router.delete("/sessions/{session_id}", status_code=204, responses={401: _E, 404: _E})
def delete_session(session_id: SessionIdPath, store: Store, who: Caller) -> Response:
    """End a session and delete its checkpoint (also one refused at restart)."""
    try:
        owned(store, session_id, who)
    except SessionRefused:
        pass  # its owner may delete it
    store.delete(session_id)
    return Response(status_code=204)


@router.post("/sessions/{session_id}/global", response_model=SessionInfo, responses=_ONE)
def reinit_global(session_id: SessionIdPath, store: Store, who: Caller) -> SessionInfo:
    """Re-initialize the filter uniformly over the map (e.g. after a kidnapping)."""
    owned(store, session_id, who)
    s = store.reinit_global(session_id)
    with s.lock:
        return session_info(store, s)


@router.get("/sessions/{session_id}/particles", response_model=Particles,
            responses=_ONE)
def get_particles(
    session_id: SessionIdPath, store: Store, who: Caller,
    max_: Annotated[int, Query(alias="max"), Field(ge=1, le=20_000), PlainInt] = 500,
) -> Particles:
    """Up to ``max`` particles (every k-th, in storage order) with their weights."""
    s = owned(store, session_id, who)
    with s.lock:
        store.touch(s)
        got = s.tracker.particles()
    if got is None:
        raise ClientError(409, "conflict", f"filter {s.spec.kind!r} has no particles",
                          "session_id", "a session with filter 'pf'")
    poses, weights = got
    n = poses.shape[0]
    idx = np.unique(np.linspace(0, n - 1, min(max_, n)).round().astype(np.int64))
    return Particles(
        n_total=n, x=poses[idx, 0].tolist(), y=poses[idx, 1].tolist(),
        yaw=wrap_angle(poses[idx, 2]).tolist(), weight=weights[idx].tolist(),
    )


# ---- blocks -------------------------------------------------------------------------------
_BLOCK_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "description": (
            "One block of B microphone samples (B = the map's SonarConfig.block_samples, "
            "40920 by default), in one of two forms. Raw little-endian samples "
            "(application/octet-stream): the odometry and encoding go in the query "
            "parameters (seq, fs_hz and speed_m_s required; yaw_rate_rad_s default 0; "
            "encoding float32 or int16, full scale 32768). JSON (application/json): "
            "everything in the body, the samples base64-encoded, no query parameters. "
            "An empty raw body means no sonar block: the filter predicts only."
        ),
        "content": {
            "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
            "application/json": {"schema": BlockJSON.model_json_schema()},
        },
    }
}

#: Query parameters a raw block must carry.
_REQUIRED_QUERY = ("seq", "fs_hz", "speed_m_s")


@router.post("/sessions/{session_id}/blocks", response_model=Estimate,
             openapi_extra=_BLOCK_BODY,
             responses={**_ONE, 400: _E, 408: _E, 413: _E, 415: _E, 422: _E})
async def post_block(session_id: SessionIdPath, request: Request, store: Store, who: Caller,
                     cfg: AppSettings, query: Annotated[BlockQuery, Query()]) -> Estimate:
    """Feed one block (with its odometry) to the session's filter; returns the estimate.

    ``seq`` must be ``last + 1 .. last + OMNISONAR_MAX_SEQ_GAP`` (the first block:
    ``0 .. OMNISONAR_MAX_SEQ_GAP``); any other is answered 409 with the accepted range and
    changes nothing. Any other rejected block (wrong length, NaN, fs mismatch) is 422 and
    changes nothing.
    """
    s = owned(store, session_id, who)  # 404 before reading a large body
    body = await request.body()
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    odo: BlockJSON | BlockQuery
    if ctype == "application/json":
        if query.model_fields_set:
            name = min(query.model_fields_set)
            raise ClientError(422, "validation", f"a JSON block carries {name} in its body, "
                              "not in the query", name, "no query parameters with JSON")
        try:
            odo = BlockJSON.model_validate_json(body)
        except ValidationError as exc:
            return validation_response(exc.errors())  # type: ignore[return-value]
        raw = _b64(odo.samples_b64)
    elif ctype in ("application/octet-stream", ""):
        for name in _REQUIRED_QUERY:
            if getattr(query, name) is None:
                raise ClientError(422, "validation", f"{name} is required", name,
                                  f"query parameter ?{name}=: {FIELD_RANGES[name]}")
        odo, raw = query, body
    else:
        raise ClientError(415, "unsupported_media_type", f"content type {ctype!r}",
                          "content-type", "application/octet-stream or application/json")
    assert odo.seq is not None and odo.fs_hz is not None and odo.speed_m_s is not None
    check_seq(odo.seq, s.last_seq, cfg.max_seq_gap)
    samples = _decode(raw, odo.encoding, s.tracker.config)
    _check_fs(odo.fs_hz, s.tracker.config)
    block = BlockInput(seq=odo.seq, samples=samples, speed_m_s=odo.speed_m_s,
                       yaw_rate_rad_s=odo.yaw_rate_rad_s)
    try:
        seq_done, est, ms = await run_in_threadpool(store.update, session_id, block)
    except ValueError as exc:  # the filter rejected the block; the session is unchanged
        raise ClientError(422, "validation", f"block rejected: {exc}", "samples",
                          None) from None
    return estimate_model(session_id, seq_done, est, ms)


def check_seq(seq: int, last_seq: int | None, max_gap: int) -> None:
    """409 unless ``seq`` is in the accepted window after ``last_seq`` (see the module doc).

    Read without the session's lock: a concurrent block can only raise ``last_seq``, and the
    store refuses ``seq <= last_seq`` under the lock, so the window stays bounded.
    """
    lo = 0 if last_seq is None else last_seq + 1
    hi = max_gap if last_seq is None else last_seq + max_gap
    if not lo <= seq <= hi:
        what = "not after the last committed seq" if seq < lo else "too far ahead"
        raise ClientError(409, "conflict", f"seq {seq} is {what} (last committed: "
                          f"{last_seq}); expected {lo}", "seq", f"{lo} <= seq <= {hi}")


def _b64(text: str) -> bytes:
    try:
        return base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        raise ClientError(422, "validation", "samples_b64 is not valid base64", "samples_b64",
                          "RFC 4648 base64 of the little-endian samples") from None


def _decode(raw: bytes, encoding: str, config: SonarConfig) -> NDArray[np.float64]:
    """Little-endian float32 / int16 bytes -> (B,) float64; 422 on wrong length or NaN.

    An empty body is allowed and means "no sonar block": the filter predicts only.
    """
    dtype, scale = (np.dtype("<f4"), 1.0) if encoding == "float32" else (np.dtype("<i2"),
                                                                        1 / 32768)
    b = config.block_samples
    if len(raw) == 0:
        return np.zeros(0)  # no block (sonar dropout): the filter predicts only
    if len(raw) != b * dtype.itemsize:
        raise ClientError(422, "validation",
                          f"block has {len(raw)} bytes = {len(raw) / dtype.itemsize:g} "
                          f"{encoding} samples", "samples",
                          f"exactly {b} {encoding} samples ({b * dtype.itemsize} bytes)")
    x = np.frombuffer(raw, dtype=dtype).astype(np.float64) * scale
    if not np.all(np.isfinite(x)):
        raise ClientError(422, "validation", "block contains NaN or inf", "samples",
                          "finite values")
    return x


def _check_fs(fs_hz: float, config: SonarConfig) -> None:
    if not math.isclose(fs_hz, config.fs_hz, rel_tol=1e-9):
        raise ClientError(422, "validation", f"fs_hz {fs_hz:g} differs from the map's sonar",
                          "fs_hz", f"{config.fs_hz:g} (no resampling)")
