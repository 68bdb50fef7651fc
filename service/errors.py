"""Error mapping of the HTTP API: every client mistake becomes a 4xx JSON body.

Bodies have the shape of :class:`service.schemas.ErrorBody`: ``error`` (a short code),
``detail`` (a sentence), and for bad input ``field`` (where) and ``allowed`` (the range).
A pure-ASGI middleware enforces the request body size limits (413) before a handler reads
anything, also for chunked bodies without a Content-Length.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.jobs import JobNotFound
from service.mapstore import MapExists, MapNotFound
from service.schemas import FIELD_RANGES
from service.sessions import InvalidSpec, SessionConflict, SessionLimit, SessionNotFound

log = logging.getLogger("omnisonar.service")


class ClientError(Exception):
    """A bad request value: status, field and allowed range go into the body."""

    def __init__(self, status: int, error: str, detail: str, field: str | None = None,
                 allowed: str | None = None, headers: dict[str, str] | None = None) -> None:
        super().__init__(detail)
        self.status, self.error, self.detail = status, error, detail
        self.field, self.allowed, self.headers = field, allowed, headers


def error_response(status: int, error: str, detail: str, field: str | None = None,
                   allowed: str | None = None, errors: list[dict[str, Any]] | None = None,
                   headers: dict[str, str] | None = None) -> JSONResponse:
    body: dict[str, Any] = {"error": error, "detail": detail, "field": field, "allowed": allowed}
    if errors is not None:
        body["errors"] = errors
    return JSONResponse(body, status_code=status, headers=headers)


_RANGE_KEYS = {"ge": ">=", "gt": ">", "le": "<=", "lt": "<", "pattern": "matches",
               "expected": "one of", "min_length": "length >=", "max_length": "length <="}


_TYPE_WORDS = {"int_parsing": "an integer", "int_from_float": "an integer",
               "float_parsing": "a number", "finite_number": "a finite number",
               "bool_parsing": "true or false", "string_type": "a string",
               "missing": "required", "extra_forbidden": "no such field",
               "json_invalid": "valid JSON", "model_attributes_type": "a JSON object",
               "list_type": "a list", "dict_type": "a JSON object"}


def _allowed(ctx: dict[str, Any] | None, kind: str, field: str | None) -> str | None:
    parts = [f"{op} {ctx[k]}" for k, op in _RANGE_KEYS.items() if ctx and k in ctx]
    if not parts and kind in _TYPE_WORDS:
        parts.append(_TYPE_WORDS[kind])
    leaf = (field or "").split(".")[-1]
    if leaf in FIELD_RANGES and FIELD_RANGES[leaf] not in parts:
        parts.append(FIELD_RANGES[leaf])
    return ", ".join(parts) or None


def validation_errors(errors: Any) -> list[dict[str, Any]]:
    """Pydantic/FastAPI error list -> [{field, msg, allowed}] with JSON-safe values."""
    out = []
    for e in errors:
        loc = [str(p) for p in e.get("loc", ()) if p not in ("body", "query", "path", "header")]
        field = ".".join(loc) or None
        kind = str(e.get("type", ""))
        out.append({"field": field, "msg": str(e.get("msg", "")), "type": kind,
                    "allowed": _allowed(e.get("ctx"), kind, field)})
    return out


def validation_response(errors: Any) -> JSONResponse:
    errs = validation_errors(errors)
    first = errs[0] if errs else {"field": None, "msg": "invalid request", "allowed": None}
    return error_response(422, "validation", str(first["msg"]), first["field"],
                          first["allowed"], errs)


def install_handlers(app: FastAPI) -> None:
    """Register the exception handlers that turn errors into JSON bodies."""

    @app.exception_handler(RequestValidationError)
    async def _validation(_: Request, exc: RequestValidationError) -> JSONResponse:
        return validation_response(exc.errors())

    @app.exception_handler(ClientError)
    async def _client(_: Request, exc: ClientError) -> JSONResponse:
        return error_response(exc.status, exc.error, exc.detail, exc.field, exc.allowed,
                              headers=exc.headers)

    @app.exception_handler(InvalidSpec)
    async def _invalid_spec(_: Request, exc: InvalidSpec) -> JSONResponse:
        return error_response(422, "validation", str(exc), exc.field, exc.allowed)

    @app.exception_handler(SessionNotFound)
    async def _no_session(_: Request, exc: SessionNotFound) -> JSONResponse:
        return error_response(404, "not_found", f"no session {exc.args[0]!r}", "session_id")

    @app.exception_handler(MapNotFound)
    async def _no_map(_: Request, exc: MapNotFound) -> JSONResponse:
        return error_response(404, "not_found", f"no map {exc.args[0]!r}", "map_id")

    @app.exception_handler(JobNotFound)
    async def _no_job(_: Request, exc: JobNotFound) -> JSONResponse:
        return error_response(404, "not_found", f"no job {exc.args[0]!r}", "job_id")

    @app.exception_handler(SessionConflict)
    async def _conflict(_: Request, exc: SessionConflict) -> JSONResponse:
        allowed = f"> {exc.last_seq}" if exc.last_seq is not None else ">= 0"
        return error_response(409, "conflict", str(exc), "seq", allowed)

    @app.exception_handler(MapExists)
    async def _exists(_: Request, exc: MapExists) -> JSONResponse:
        return error_response(409, "conflict", f"map {exc.args[0]!r} exists; use overwrite",
                              "map_id")

    @app.exception_handler(SessionLimit)
    async def _limit(_: Request, exc: SessionLimit) -> JSONResponse:
        return error_response(429, "too_many_sessions", str(exc), None, None,
                              headers={"Retry-After": "10"})

    @app.exception_handler(StarletteHTTPException)
    async def _http(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        if isinstance(exc, _BodyTooLarge):
            return error_response(413, "too_large", str(exc.detail), "body",
                                  f"<= {exc.limit} bytes")
        return error_response(exc.status_code, "http", str(exc.detail),
                              headers=getattr(exc, "headers", None))

    @app.exception_handler(Exception)
    async def _bug(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return error_response(500, "internal", f"internal error ({type(exc).__name__})")


class BodyLimitMiddleware:
    """Answer 413 when a request body exceeds its limit (declared or streamed).

    ``limit_for(scope)`` gives the limit in bytes for a request.
    """

    def __init__(self, app: ASGIApp, limit_for: Callable[[Scope], int]) -> None:
        self.app = app
        self.limit_for = limit_for

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.limit_for(scope)
        declared = dict(scope.get("headers") or []).get(b"content-length")
        if declared is not None:
            try:
                too_big = int(declared) > limit
            except ValueError:
                too_big = False
            if too_big:
                await _send_413(scope, receive, send, limit)
                return
        seen = 0
        started = False

        async def limited_receive() -> Message:
            nonlocal seen
            msg = await receive()
            if msg["type"] == "http.request":
                seen += len(msg.get("body", b""))
                if seen > limit:
                    raise _BodyTooLarge(limit)
            return msg

        async def tracking_send(msg: Message) -> None:
            nonlocal started
            if msg["type"] == "http.response.start":
                started = True
            await send(msg)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except _BodyTooLarge:
            if not started:
                await _send_413(scope, receive, send, limit)


class _BodyTooLarge(StarletteHTTPException):
    """Raised from ``receive``; an HTTPException so FastAPI's body parsing re-raises it."""

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body over {limit} bytes")
        self.limit = limit


async def _send_413(scope: Scope, receive: Receive, send: Send, limit: int) -> None:
    resp = error_response(413, "too_large", f"request body over {limit} bytes", "body",
                          f"<= {limit} bytes")
    await resp(scope, receive, send)


Handler = Callable[[Request], Awaitable[Any]]
