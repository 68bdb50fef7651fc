"""``/maps`` and ``/jobs``: list, inspect, render, upload and build wall maps.

Reading maps needs any key; uploading, building and deleting need an admin key, as does
reading a build job (see :mod:`service.auth`).
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Query, Request, Response
from starlette.concurrency import run_in_threadpool

from service.auth import Admin, Caller
from service.deps import get_app_settings, get_jobs, get_maps, get_sessions
from service.errors import ClientError
from service.jobs import JobRecord, JobRunner
from service.mapstore import MapInUse, MapNotFound, MapStore
from service.quotas import Gate
from service.schemas import ID_PATTERN, BuildRequest, ErrorBody, Job, MapInfo, MapList
from service.sessions import SessionStore
from service.settings import Settings

router = APIRouter(tags=["maps"])

#: Id of the embedded paper-scene map built on first start.
DEFAULT_MAP_ID = "default"

MapIdPath = Annotated[str, Path(pattern=ID_PATTERN, description="map identifier")]
_E: dict[str, Any] = {"model": ErrorBody}
_AUTH: dict[int | str, dict[str, Any]] = {401: _E}
_ADMIN: dict[int | str, dict[str, Any]] = {401: _E, 403: _E}


@router.get("/maps", response_model=MapList, responses=_AUTH)
def list_maps(_: Caller, maps: Annotated[MapStore, Depends(get_maps)],
              jobs: Annotated[JobRunner, Depends(get_jobs)]) -> MapList:
    """All stored maps, and the ids still being built."""
    infos = []
    for map_id in maps.ids():
        try:
            infos.append(MapInfo(**maps.info(map_id)))
        except (ValueError, KeyError):
            continue  # a file that is not a valid map is not listed
    return MapList(maps=infos, building=jobs.active_map_ids())


def _info(maps: MapStore, map_id: str) -> MapInfo:
    try:
        return MapInfo(**maps.info(map_id))
    except MapNotFound:
        raise
    except (ValueError, KeyError):  # a file stored before uploads were validated
        raise ClientError(404, "not_found", f"map {map_id!r} is stored but unreadable; "
                          "upload it again with overwrite=true", "map_id") from None


@router.get("/maps/{map_id}", response_model=MapInfo, responses={**_AUTH, 404: _E})
def get_map(map_id: MapIdPath, _: Caller,
            maps: Annotated[MapStore, Depends(get_maps)]) -> MapInfo:
    """Metadata of one map: grid shape, origin, resolution, method, provenance, sonar."""
    return _info(maps, map_id)


@router.get("/maps/{map_id}/image.png",
            responses={200: {"content": {"image/png": {}}}, **_AUTH, 404: _E},
            response_class=Response)
def get_map_image(map_id: MapIdPath, _: Caller,
                  maps: Annotated[MapStore, Depends(get_maps)]) -> Response:
    """The map G as a grey-scale PNG (row 0 at the bottom: y grows upwards)."""
    _info(maps, map_id)
    return Response(maps.png(map_id), media_type="image/png")


_MAP_FILE = "a map file (.npz, format omnisonar-map-2 or omnisonar-map-1)"
_UPLOAD_BODY = {
    "requestBody": {
        "required": True,
        "content": {"application/octet-stream": {"schema": {"type": "string",
                                                             "format": "binary"}}},
        "description": _MAP_FILE,
    }
}


def _upload_gate(request: Request) -> Gate:
    gate: Gate = request.app.state.uploads  # built in the lifespan
    return gate


@router.post("/maps", status_code=201, response_model=MapInfo, openapi_extra=_UPLOAD_BODY,
             responses={**_ADMIN, 408: _E, 409: _E, 413: _E, 422: _E, 429: _E, 503: _E})
async def upload_map(
    request: Request,
    who: Admin,
    map_id: Annotated[str, Query(pattern=ID_PATTERN, description="id to store it under")],
    maps: Annotated[MapStore, Depends(get_maps)],
    cfg: Annotated[Settings, Depends(get_app_settings)],
    overwrite: bool = False,
) -> MapInfo:
    """Upload a map file (admin key); it is validated completely, then stored atomically
    under ``map_id``. Array sizes are checked from the file's headers before anything is
    decompressed; one upload per key and ``OMNISONAR_MAX_UPLOADS`` in all at once."""
    with _upload_gate(request).enter(who.name):
        data = await request.body()
        if not data:
            raise ClientError(422, "validation", "empty body: send the map file bytes", "body",
                              "a map file (.npz)")
        await run_in_threadpool(maps.save_upload, map_id, data, overwrite, cfg.max_map_cells,
                                cfg.max_body_bytes // 4)
        del data
    return _info(maps, map_id)


@router.delete("/maps/{map_id}", status_code=204, response_class=Response,
               responses={**_ADMIN, 404: _E, 409: _E})
def delete_map(map_id: MapIdPath, _: Admin,
               maps: Annotated[MapStore, Depends(get_maps)],
               sessions: Annotated[SessionStore, Depends(get_sessions)],
               jobs: Annotated[JobRunner, Depends(get_jobs)]) -> Response:
    """Delete a stored map (admin key). Refused (409 ``in_use``) while a live session uses
    it or a build is writing it; delete those sessions first."""
    if map_id in jobs.active_map_ids():
        raise MapInUse(map_id, f"map {map_id!r} is being built")
    maps.delete(map_id, lambda: sessions.sessions_on(map_id))
    return Response(status_code=204)


@router.post("/maps/build", status_code=202, response_model=Job,
             responses={**_ADMIN, 409: _E, 422: _E, 429: _E, 503: _E})
def build_map(
    req: BuildRequest,
    who: Admin,
    response: Response,
    maps: Annotated[MapStore, Depends(get_maps)],
    jobs: Annotated[JobRunner, Depends(get_jobs)],
    cfg: Annotated[Settings, Depends(get_app_settings)],
) -> Job:
    """Start a batch build from run files in the server's runs directory (admin key; 202 +
    job). At most ``OMNISONAR_MAX_BUILD_QUEUE`` builds wait or run (503 beyond) and
    ``OMNISONAR_MAX_JOBS_PER_KEY`` per key (429 beyond)."""
    from service import builds

    if req.method not in builds.methods():
        raise ClientError(422, "validation", f"unknown method {req.method!r}", "method",
                          f"one of {sorted(builds.methods())}")
    paths = []
    for i, name in enumerate(req.runs):
        path = cfg.runs_path / (name if name.endswith(".npz") else f"{name}.npz")
        if not path.is_file():
            raise ClientError(422, "validation", f"no run file {name!r} on the server",
                              f"runs.{i}", "the name of a run file in the server's runs "
                              "directory (OMNISONAR_RUNS_DIR)")
        paths.append(path)
    if (maps.exists(req.map_id) and not req.overwrite) or req.map_id in jobs.active_map_ids():
        raise ClientError(409, "conflict", f"map {req.map_id!r} exists or is being built",
                          "map_id", "a new id, or overwrite=true")
    rec = jobs.submit("build", req.map_id,
                      lambda progress: builds.build_to_store(maps, req.map_id, paths,
                                                             req.method, progress),
                      owner=who.name)
    response.headers["Location"] = f"/jobs/{rec.id}"
    return _job(rec)


@router.get("/jobs/{job_id}", response_model=Job, responses={**_ADMIN, 404: _E})
def get_job(job_id: Annotated[str, Path(max_length=64)], _: Admin,
            jobs: Annotated[JobRunner, Depends(get_jobs)]) -> Job:
    """Status and progress of a map build (admin key). A build the server was stopped during
    is ``failed`` with a message saying so."""
    return _job(jobs.get(job_id))


def _job(rec: JobRecord) -> Job:
    d = rec.to_dict()
    d.pop("owner", None)
    return Job(**d)


def submit_default_map(maps: MapStore, jobs: JobRunner, cfg: Settings) -> JobRecord:
    """Start the background build of the embedded paper-scene map ``default``."""
    from service import builds

    return jobs.submit("default-map", DEFAULT_MAP_ID,
                       lambda progress: builds.build_default_map(maps, DEFAULT_MAP_ID,
                                                                 progress))
