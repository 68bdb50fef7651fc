"""Schemathesis over the service's own OpenAPI schema, with every check (issue 17).

Every operation in ``/openapi.json`` is called with inputs schemathesis generates from the
schema (valid and invalid), bounded to a few examples per operation so the suite stays fast,
and every answer is checked against the document: no 5xx, status codes, content types,
headers and bodies as documented, invalid data rejected, undeclared methods answered 405
with ``Allow``. The document itself must validate as OpenAPI 3.1. The hand-written
hypothesis fuzz in ``test_fuzz.py`` covers what a schema cannot describe (raw binary blocks,
oversize bodies, non-finite JSON tokens).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.config import SchemathesisConfig

from mapping.files import write_map
from service.app import create_app
from service.settings import Settings
from tests.service.helpers import raster_map

LIMIT = 256 * 1024


ADMIN_KEY = "schemathesis-admin-key-0123456789"


def _app(root: Path, **keys: str):  # type: ignore[no-untyped-def]
    write_map(root / "maps" / "room.npz", raster_map())
    cfg = Settings(maps_dir=root / "maps", sessions_dir=root / "sessions", runs_dir=root / "runs",
                   default_map=False, max_sessions=64, max_particles=500, max_body_bytes=LIMIT,
                   max_map_bytes=LIMIT, session_idle_s=3600, max_sessions_per_key=64,
                   **keys)  # type: ignore[arg-type]
    return create_app(cfg)


#: Operations whose valid-by-schema inputs may still be refused with 422 for what a schema
#: cannot say: an upload must be a map file (not any bytes), a session needs a stored map id
#: and a pose on that map, a build needs run files that exist on the server.
SEMANTIC_422 = [("POST", "/maps"), ("POST", "/sessions"), ("POST", "/maps/build")]
_ACCEPTED = ["2xx", "401", "403", "404", "409", "422", "429", "503"]
_OPERATIONS = [{"include-method": method, "include-path": path,
                "checks": {"positive_data_acceptance": {"expected-statuses": _ACCEPTED}}}
               for method, path in SEMANTIC_422]
CONFIG = SchemathesisConfig.from_dict({"operations": _OPERATIONS})

_TMP = __import__("tempfile").mkdtemp
_APP = _app(Path(_TMP(prefix="omnisonar-schemathesis-")))
schema = schemathesis.openapi.from_asgi("/openapi.json", _APP, config=CONFIG)
#: The same API with keys required: the document declares its security, schemathesis sends
#: the admin key, and its ``ignored_auth`` check also calls without it (must be 401).
_KEYED = _app(Path(_TMP(prefix="omnisonar-schemathesis-keys-")), admin_keys=ADMIN_KEY)
keyed = schemathesis.openapi.from_asgi("/openapi.json", _KEYED, config=CONFIG)


@pytest.fixture(scope="module", autouse=True)
def _lifespan() -> object:
    """Run the apps' lifespans (map store, session store) around the module's calls."""
    from fastapi.testclient import TestClient

    with TestClient(_APP) as client, TestClient(_KEYED):
        yield client


def test_openapi_document_is_valid_3_1(_lifespan: object) -> None:
    from openapi_spec_validator import validate
    from openapi_spec_validator.validation import OpenAPIV31SpecValidator

    doc = _lifespan.get("/openapi.json").json()  # type: ignore[attr-defined]
    assert doc["openapi"].startswith("3.1")
    validate(doc, cls=OpenAPIV31SpecValidator)


@schema.parametrize()
@settings(max_examples=20, deadline=None, suppress_health_check=list(HealthCheck))
def test_all_checks(case: schemathesis.Case) -> None:
    case.call_and_validate()


@keyed.parametrize()
@settings(max_examples=8, deadline=None, suppress_health_check=list(HealthCheck))
def test_all_checks_with_keys(case: schemathesis.Case) -> None:
    case.call_and_validate(headers={"Authorization": f"Bearer {ADMIN_KEY}"})
