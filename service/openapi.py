"""The OpenAPI document of the service, made to describe what the server really answers.

FastAPI documents its own validation error (``HTTPValidationError``, ``{detail: [...]}``) for
422, but the service answers every error with :class:`~service.schemas.ErrorBody`; it does
not know the answers that middleware and exception handlers send (400 undecodable body, 408
slow body, 413 body too large) nor the security of the routes. :func:`contract` rewrites the
generated document accordingly; the result validates as OpenAPI 3.1 (the tests check it with
``openapi-spec-validator`` and schemathesis, all checks).
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

_ERROR = {"$ref": "#/components/schemas/ErrorBody"}
_FASTAPI_422 = "#/components/schemas/HTTPValidationError"
_WORDS = {400: "Body not decodable (e.g. JSON that is not UTF-8)",
          401: "No key, or an unknown one", 403: "The key is not an admin key",
          408: "The body did not arrive in time", 413: "Request body too large",
          422: "Invalid input; the body names the field and the allowed range"}
#: Routes anyone may call (no key): liveness and the documentation itself.
PUBLIC_PATHS = ("/health",)


def contract(app: FastAPI, keys_enabled: bool) -> dict[str, Any]:
    """The app's OpenAPI document with the real error bodies, status codes and security."""
    doc = get_openapi(title=app.title, version=app.version, summary=app.summary,
                      description=app.description, routes=app.routes)
    schemas = doc.setdefault("components", {}).setdefault("schemas", {})
    schemas.pop("HTTPValidationError", None)
    schemas.pop("ValidationError", None)
    if keys_enabled:
        doc["components"]["securitySchemes"] = {
            "bearer": {"type": "http", "scheme": "bearer",
                       "description": "an API key: Authorization: Bearer <key>"},
            "apiKey": {"type": "apiKey", "in": "header", "name": "X-API-Key"},
        }
    for path, item in doc.get("paths", {}).items():
        for op in item.values():
            _fix_operation(op, path, keys_enabled)
    return doc


def _fix_operation(op: dict[str, Any], path: str, keys_enabled: bool) -> None:
    responses = op.setdefault("responses", {})
    for code, resp in responses.items():
        content = resp.get("content", {}).get("application/json")
        if content is not None and content.get("schema", {}).get("$ref") == _FASTAPI_422:
            content["schema"] = dict(_ERROR)
        if code.isdigit() and int(code) in _WORDS and code != "200":
            resp["description"] = _WORDS[int(code)]
    body = op.get("requestBody", {}).get("content", {})
    if body:
        _add(responses, 413)
        _add(responses, 408)
    if "application/json" in body:
        _add(responses, 400)
    if path not in PUBLIC_PATHS and keys_enabled:
        op["security"] = [{"bearer": []}, {"apiKey": []}]
    if path not in PUBLIC_PATHS:
        _add(responses, 401)


def _add(responses: dict[str, Any], code: int) -> None:
    responses.setdefault(str(code), {"description": _WORDS[code],
                                     "content": {"application/json": {"schema": dict(_ERROR)}}})
