"""Dependencies handing the lifespan's long-lived objects to the routers."""

from __future__ import annotations

from fastapi import Request

from service.jobs import JobRunner
from service.mapstore import MapStore
from service.sessions import SessionStore
from service.settings import Settings


def get_maps(request: Request) -> MapStore:
    """The map store built in the lifespan."""
    maps: MapStore = request.app.state.maps
    return maps


def get_sessions(request: Request) -> SessionStore:
    """The session store built in the lifespan."""
    store: SessionStore = request.app.state.sessions
    return store


def get_jobs(request: Request) -> JobRunner:
    """The background job runner."""
    jobs: JobRunner = request.app.state.jobs
    return jobs


def get_app_settings(request: Request) -> Settings:
    """The settings the app was started with."""
    cfg: Settings = request.app.state.settings
    return cfg
