"""``/maps`` and ``/jobs``: list, inspect, render, upload and build wall maps."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Query, Request, Response

from service.deps import get_app_settings, get_jobs, get_maps
from service.errors import ClientError
from service.jobs import JobRecord, JobRunner
from service.mapstore import MapStore
from service.schemas import ID_PATTERN, BuildRequest, ErrorBody, Job, MapInfo, MapList
from service.settings import Settings

router = APIRouter(tags=["maps"])

#: Id of the embedded paper-scene map built on first start.
DEFAULT_MAP_ID = "default"

MapIdPath = Annotated[str, Path(pattern=ID_PATTERN, description="map identifier")]
_404: dict[int | str, dict[str, Any]] = {404: {"model": ErrorBody}}


@router.get("/maps", response_model=MapList)
def list_maps(maps: Annotated[MapStore, Depends(get_maps)],
              jobs: Annotated[JobRunner, Depends(get_jobs)]) -> MapList:
    """All stored maps, and the ids still being built."""
    infos = []
    for map_id in maps.ids():
        try:
            infos.append(MapInfo(**maps.info(map_id)))
        except (ValueError, KeyError):
            continue  # a file that is not a valid map is not listed
    return MapList(maps=infos, building=jobs.active_map_ids())


@router.get("/maps/{map_id}", response_model=MapInfo, responses=_404)
def get_map(map_id: MapIdPath, maps: Annotated[MapStore, Depends(get_maps)]) -> MapInfo:
    """Metadata of one map: grid shape, origin, resolution, method, provenance, sonar."""
    return MapInfo(**maps.info(map_id))


@router.get("/maps/{map_id}/image.png", responses={200: {"content": {"image/png": {}}}, **_404},
            response_class=Response)
def get_map_image(map_id: MapIdPath, maps: Annotated[MapStore, Depends(get_maps)]) -> Response:
    """The map G as a grey-scale PNG (row 0 at the bottom: y grows upwards)."""
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


@router.post("/maps", status_code=201, response_model=MapInfo, openapi_extra=_UPLOAD_BODY,
             responses={409: {"model": ErrorBody}, 413: {"model": ErrorBody},
                        422: {"model": ErrorBody}})
async def upload_map(
    request: Request,
    map_id: Annotated[str, Query(pattern=ID_PATTERN, description="id to store it under")],
    maps: Annotated[MapStore, Depends(get_maps)],
    overwrite: bool = False,
) -> MapInfo:
    """Upload a map file; it is validated, then stored atomically under ``map_id``."""
    from starlette.concurrency import run_in_threadpool

    data = await request.body()
    if not data:
        raise ClientError(422, "validation", "empty body: send the map file bytes", "body",
                          "a map file (.npz)")
    try:
        await run_in_threadpool(maps.save_upload, map_id, data, overwrite)
    except ValueError as exc:
        raise ClientError(422, "validation", f"not a valid map file: {exc}", "body",
                          _MAP_FILE) from None
    return MapInfo(**maps.info(map_id))


@router.post("/maps/build", status_code=202, response_model=Job,
             responses={409: {"model": ErrorBody}, 422: {"model": ErrorBody}})
def build_map(
    req: BuildRequest,
    response: Response,
    maps: Annotated[MapStore, Depends(get_maps)],
    jobs: Annotated[JobRunner, Depends(get_jobs)],
    cfg: Annotated[Settings, Depends(get_app_settings)],
) -> Job:
    """Start a batch build from run files in the server's runs directory (202 + job)."""
    from service import builds

    if req.method not in builds.methods():
        raise ClientError(422, "validation", f"unknown method {req.method!r}", "method",
                          f"one of {sorted(builds.methods())}")
    paths = []
    for i, name in enumerate(req.runs):
        path = cfg.runs_path / (name if name.endswith(".npz") else f"{name}.npz")
        if not path.is_file():
            raise ClientError(422, "validation", f"no run file {name!r} on the server",
                              f"runs.{i}", f"files in {cfg.runs_path}")
        paths.append(path)
    if (maps.exists(req.map_id) and not req.overwrite) or req.map_id in jobs.active_map_ids():
        raise ClientError(409, "conflict", f"map {req.map_id!r} exists or is being built",
                          "map_id", "a new id, or overwrite=true")
    rec = jobs.submit("build", req.map_id,
                      lambda progress: builds.build_to_store(maps, req.map_id, paths,
                                                             req.method, progress))
    response.headers["Location"] = f"/jobs/{rec.id}"
    return _job(rec)


@router.get("/jobs/{job_id}", response_model=Job, responses=_404)
def get_job(job_id: Annotated[str, Path(max_length=64)],
            jobs: Annotated[JobRunner, Depends(get_jobs)]) -> Job:
    """Status and progress of a map build."""
    return _job(jobs.get(job_id))


def _job(rec: JobRecord) -> Job:
    return Job(**rec.to_dict())


def submit_default_map(maps: MapStore, jobs: JobRunner, cfg: Settings) -> JobRecord:
    """Start the background build of the embedded paper-scene map ``default``."""
    from service import builds

    return jobs.submit("default-map", DEFAULT_MAP_ID,
                       lambda progress: builds.build_default_map(maps, DEFAULT_MAP_ID,
                                                                 progress))
