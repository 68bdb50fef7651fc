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
OMNISONAR_CHECKPOINT      checkpoint sessions (``true``; ``false``: in memory only)
OMNISONAR_CHECKPOINT_FSYNC  fsync each checkpoint: survives power loss, not only a crash (``true``)
OMNISONAR_CHECKPOINT_EVERY_BLOCKS  checkpoint every N-th block (1: every block; 0: not by count)
OMNISONAR_CHECKPOINT_EVERY_S  also checkpoint when the last one is older than T s (0: not by time)
OMNISONAR_API_KEYS        comma-separated client keys (empty: no keys, loopback clients only)
OMNISONAR_ADMIN_KEYS      comma-separated admin keys: map uploads, builds, deletes; every session
OMNISONAR_KEYS_FILE       file of keys, one ``user <key>`` or ``admin <key>`` a line
OMNISONAR_HOST            the address ``omnisonar serve`` binds (``127.0.0.1``)
OMNISONAR_ALLOW_INSECURE  serve a non-loopback address without keys (``false``: refuse)
OMNISONAR_MAX_SESSIONS_PER_KEY  sessions one key may hold open (16)
OMNISONAR_MAX_JOBS_PER_KEY      map builds one key may have queued or running (2)
OMNISONAR_MAX_BUILD_QUEUE       builds queued or running on the server (4; then 503)
OMNISONAR_MAX_UPLOADS           map uploads validated at once (2; then 503)
OMNISONAR_MAX_MAP_CELLS   largest map G (cells) an upload may hold (1e6; ~0.5 KB/cell of tables)
OMNISONAR_MAX_SEQ_GAP     largest step of ``seq`` between blocks (1000; first block: 0..gap)
OMNISONAR_READ_TIMEOUT_S  seconds a client may take to send a request (headers or body) (30)
OMNISONAR_KEEP_ALIVE_S    idle keep-alive seconds before the server closes a connection (5)
OMNISONAR_MAX_CONNECTIONS concurrent connections before uvicorn answers 503 (256)
OMNISONAR_MALLOC_ARENAS   glibc malloc arenas for ``omnisonar serve`` (2; 0: glibc's default,
                          8 per core): per-thread arenas let the RSS climb ~40 MiB a minute
                          under load (benchmarks/service_load; with 2 it stays ~400 MiB)
========================  ==================================================================
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Annotated

from pydantic import Field, SecretStr
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
    # the checkpoint policy (service.sessions.CheckpointPolicy): the safe default writes after
    # every block; a crash loses at most every_blocks - 1 blocks or every_s seconds otherwise
    checkpoint_every_blocks: Annotated[int, Field(ge=0, le=1_000_000)] = 1
    checkpoint_every_s: Annotated[float, Field(ge=0, le=86_400)] = 0.0
    # access control (service/auth.py)
    api_keys: SecretStr = SecretStr("")
    admin_keys: SecretStr = SecretStr("")
    keys_file: Path | None = None
    host: str = "127.0.0.1"
    allow_insecure: bool = False
    # bounded resources
    max_sessions_per_key: Annotated[int, Field(ge=1, le=10_000)] = 16
    max_jobs_per_key: Annotated[int, Field(ge=1, le=1000)] = 2
    max_build_queue: Annotated[int, Field(ge=1, le=1000)] = 4
    max_uploads: Annotated[int, Field(ge=1, le=64)] = 2
    max_map_cells: Annotated[int, Field(ge=100, le=100_000_000)] = 1_000_000
    max_seq_gap: Annotated[int, Field(ge=1, le=1_000_000)] = 1000
    read_timeout_s: Annotated[float, Field(gt=0, le=3600)] = 30.0
    keep_alive_s: Annotated[float, Field(gt=0, le=3600)] = 5.0
    max_connections: Annotated[int, Field(ge=1, le=100_000)] = 256
    malloc_arenas: Annotated[int, Field(ge=0, le=1024)] = 2

    @property
    def sessions_path(self) -> Path:
        """Directory of session checkpoints."""
        return self.sessions_dir or self.maps_dir.parent / "sessions"

    @property
    def jobs_path(self) -> Path:
        """Directory of build-job records (kept across restarts)."""
        return self.maps_dir.parent / "jobs"

    @property
    def runs_path(self) -> Path:
        """Directory of run files available to map builds."""
        return self.runs_dir or self.maps_dir.parent / "runs"


@lru_cache
def get_settings() -> Settings:
    """The process-wide settings (cached: the environment is read once)."""
    return Settings()
