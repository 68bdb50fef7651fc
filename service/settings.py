"""Settings of the localization service, read from ``OMNISONAR_*`` environment variables.

Every field can be set by an environment variable named ``OMNISONAR_<FIELD>`` (upper case),
e.g. ``OMNISONAR_MAPS_DIR=/srv/maps``. The app reads them once through the cached
dependency :func:`get_settings`; tests replace it with ``app.dependency_overrides`` or pass a
:class:`Settings` to :func:`service.app.create_app`.

========================  ==================================================================
variable                  meaning (default)
========================  ==================================================================
OMNISONAR_MAPS_DIR        directory of map files ``<map_id>.npz`` (``var/maps``)
OMNISONAR_SESSIONS_DIR    session checkpoints; empty = ``<maps_dir>/../sessions``
OMNISONAR_RUNS_DIR        run files ``POST /maps/build`` reads; empty = ``<maps_dir>/../runs``
OMNISONAR_DEFAULT_MAP     build the paper-scene map ``default`` on first start (``true``)
OMNISONAR_MAX_SESSIONS    cap on concurrent sessions (64)
OMNISONAR_SESSION_IDLE_S  idle seconds after which a session expires (900)
OMNISONAR_EXPIRY_CHECK_S  seconds between idle-expiry sweeps (10)
OMNISONAR_MAX_PARTICLES   largest particle count a session may ask for (20000)
OMNISONAR_MAX_BODY_BYTES  largest request body except map uploads (1 MiB)
OMNISONAR_MAX_MAP_BYTES   largest map upload (64 MiB)
OMNISONAR_CHECKPOINT      checkpoint sessions after every update (``true``)
OMNISONAR_CHECKPOINT_FSYNC  fsync each checkpoint: survives power loss, not only a crash (``true``)
========================  ==================================================================
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Annotated

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    """Service configuration; see the module docstring for the environment variables."""

    model_config = SettingsConfigDict(env_prefix="OMNISONAR_", frozen=True)

    maps_dir: Path = Path("var/maps")
    sessions_dir: Path | None = None
    runs_dir: Path | None = None
    default_map: bool = True
    max_sessions: Annotated[int, Field(ge=1, le=10_000)] = 64
    session_idle_s: Annotated[float, Field(gt=0)] = 900.0
    expiry_check_s: Annotated[float, Field(gt=0)] = 10.0
    max_particles: Annotated[int, Field(ge=10, le=1_000_000)] = 20_000
    max_body_bytes: Annotated[int, Field(ge=1024)] = 1 << 20
    max_map_bytes: Annotated[int, Field(ge=1024)] = 64 << 20
    checkpoint: bool = True
    checkpoint_fsync: bool = True

    @property
    def sessions_path(self) -> Path:
        """Directory of session checkpoints."""
        return self.sessions_dir or self.maps_dir.parent / "sessions"

    @property
    def runs_path(self) -> Path:
        """Directory of run files available to map builds."""
        return self.runs_dir or self.maps_dir.parent / "runs"


@lru_cache
def get_settings() -> Settings:
    """The process-wide settings (cached: the environment is read once)."""
    return Settings()
