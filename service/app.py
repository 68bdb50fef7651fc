"""The FastAPI application: maps and live localization sessions over HTTP.

``create_app()`` builds the app; long-lived objects (map store, session store, job runner) are
made in the lifespan from :class:`~service.settings.Settings` (the cached ``get_settings``
dependency, or whatever ``app.dependency_overrides[get_settings]`` returns) and hung on
``app.state``. Run it with ``omnisonar serve`` or
``uvicorn --factory service.app:create_app``.

Start-up refuses a non-loopback ``OMNISONAR_HOST`` without API keys (:mod:`service.auth`),
removes temporary files a killed upload left, restores sessions and build-job records.
The OpenAPI document is :func:`service.openapi.contract`: the error bodies and status codes
the server really sends.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator, Callable
from typing import Any

from fastapi import FastAPI
from starlette.concurrency import run_in_threadpool
from starlette.types import Scope

from service.auth import KeyRing, check_bind
from service.errors import BodyLimitMiddleware, install_handlers
from service.jobs import JobRunner
from service.mapstore import MapStore
from service.openapi import contract
from service.quotas import Gate
from service.routers import maps as maps_router
from service.routers import sessions as sessions_router
from service.routers import view as view_router
from service.sessions import CheckpointPolicy, SessionStore, TrackerFactory
from service.settings import Settings, get_settings

log = logging.getLogger("omnisonar.service")

FactoryMaker = Callable[[MapStore], TrackerFactory]


def _default_factory(maps: MapStore) -> TrackerFactory:
    from service.localizer import LocalizationFactory

    return LocalizationFactory(maps)


def create_app(settings: Settings | None = None, factory: FactoryMaker | None = None,
               start_default_map: bool | None = None) -> FastAPI:
    """Build the service app.

    Parameters
    ----------
    settings : Settings, optional
        Fixed settings; default: the ``get_settings`` dependency (environment), honouring
        ``app.dependency_overrides``.
    factory : callable, optional
        ``MapStore -> TrackerFactory``; default the real filter from ``localization``.
    start_default_map : bool, optional
        Override ``settings.default_map`` (tests switch the background build off).
    """

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        cfg = _resolve_settings(app, settings)
        keys = KeyRing.from_settings(cfg)
        check_bind(cfg, keys)
        app.state.keys, app.state.settings = keys, cfg
        app.state.uploads = Gate("map uploads", cfg.max_uploads, 1)
        maps = MapStore(cfg.maps_dir)
        orphans = maps.clean_orphans()
        if orphans:
            log.info("removed %d temporary file(s) of interrupted writes", len(orphans))
        store = SessionStore(
            cfg.sessions_path if cfg.checkpoint else None, cfg.max_sessions,
            cfg.session_idle_s, (factory or _default_factory)(maps),
            policy=CheckpointPolicy(cfg.checkpoint_every_blocks, cfg.checkpoint_every_s,
                                    cfg.checkpoint_fsync),
        )
        loaded, skipped = await run_in_threadpool(store.reload)
        if loaded or skipped:
            log.info("restored %d session(s); skipped %s", len(loaded), skipped)
        jobs = JobRunner(directory=cfg.jobs_path, max_queue=cfg.max_build_queue,
                         max_per_owner=cfg.max_jobs_per_key)
        app.state.settings, app.state.maps = cfg, maps
        app.state.sessions, app.state.jobs = store, jobs
        build_default = cfg.default_map if start_default_map is None else start_default_map
        if build_default and not maps.exists(maps_router.DEFAULT_MAP_ID):
            maps_router.submit_default_map(maps, jobs, cfg)
        expiry = asyncio.create_task(_expire_forever(store, cfg.expiry_check_s))
        try:
            yield
        finally:
            expiry.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await expiry
            await run_in_threadpool(store.flush)  # a graceful stop loses no block
            jobs.shutdown()

    app = FastAPI(
        title="omnisonar localization service",
        version="1",
        summary="Maps and live Doppler-sonar localization sessions (REP-103 poses).",
        lifespan=lifespan,
    )
    install_handlers(app)
    app.add_middleware(BodyLimitMiddleware, limit_for=_limit_for(app, settings),
                       timeout_for=lambda _: float(_cfg(app, settings).read_timeout_s))
    app.include_router(maps_router.router)
    app.include_router(sessions_router.router)
    app.include_router(view_router.router)

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            keys = getattr(app.state, "keys", None)
            enabled = keys.enabled if keys is not None else \
                KeyRing.from_settings(_cfg(app, settings)).enabled
            app.openapi_schema = contract(app, enabled)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]

    @app.get("/health", tags=["meta"])
    def health() -> dict[str, Any]:
        """Liveness: counts of maps, sessions and running jobs (no key needed)."""
        st = app.state
        return {"status": "ok", "maps": len(st.maps.ids()), "sessions": len(st.sessions),
                "building": st.jobs.active_map_ids()}

    return app


def _resolve_settings(app: FastAPI, fixed: Settings | None) -> Settings:
    if fixed is not None:
        return fixed
    return app.dependency_overrides.get(get_settings, get_settings)()


def _cfg(app: FastAPI, fixed: Settings | None) -> Settings:
    cfg: Settings | None = getattr(app.state, "settings", None)
    return cfg or _resolve_settings(app, fixed)


def _limit_for(app: FastAPI, fixed: Settings | None) -> Callable[[Scope], int]:
    def limit(scope: Scope) -> int:
        cfg = _cfg(app, fixed)
        if scope.get("method") == "POST" and scope.get("path", "").rstrip("/") == "/maps":
            return int(cfg.max_map_bytes)
        return int(cfg.max_body_bytes)

    return limit


async def _expire_forever(store: SessionStore, every_s: float) -> None:
    while True:
        await asyncio.sleep(every_s)
        gone = await run_in_threadpool(store.expire)
        if gone:
            log.info("expired idle session(s) %s", gone)
