"""Schemathesis over the service's own OpenAPI schema: zero 5xx answers (issue 7).

Every operation in ``/openapi.json`` is called with inputs schemathesis generates from the
schema (valid and invalid), bounded to a few examples per operation so the suite stays fast.
The hand-written hypothesis fuzz in ``test_service_fuzz.py`` covers what a schema cannot
describe (raw binary blocks, oversize bodies, non-finite JSON tokens).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings

from mapping.files import write_map
from service.app import create_app
from service.settings import Settings
from tests.service.helpers import raster_map

LIMIT = 256 * 1024


def _app(root: Path):  # type: ignore[no-untyped-def]
    write_map(root / "maps" / "room.npz", raster_map())
    cfg = Settings(maps_dir=root / "maps", sessions_dir=root / "sessions", runs_dir=root / "runs",
                   default_map=False, max_sessions=64, max_particles=500, max_body_bytes=LIMIT,
                   max_map_bytes=LIMIT, session_idle_s=3600)
    return create_app(cfg)


_ROOT = Path(__import__("tempfile").mkdtemp(prefix="omnisonar-schemathesis-"))
_APP = _app(_ROOT)
schema = schemathesis.openapi.from_asgi("/openapi.json", _APP)


@pytest.fixture(scope="module", autouse=True)
def _lifespan() -> object:
    """Run the app's lifespan (map store, session store) around the module's calls."""
    from fastapi.testclient import TestClient

    with TestClient(_APP) as client:
        yield client


@schema.parametrize()
@settings(max_examples=15, deadline=None,
          suppress_health_check=list(HealthCheck))
def test_no_server_errors(case: schemathesis.Case) -> None:
    response = case.call()
    assert response.status_code < 500, (case.method, case.path, response.status_code,
                                        response.text[:300])
