"""Error mapping of the HTTP API: every client mistake becomes a 4xx JSON body.

Bodies have the shape of :class:`service.schemas.ErrorBody`: ``error`` (a short code),
``detail`` (a sentence), and for bad input ``field`` (where) and ``allowed`` (the range).
A pure-ASGI middleware enforces the request body size limits (413) before a handler reads
anything, also for chunked bodies without a Content-Length, and a read timeout (408) on a
client that sends its body too slowly. No message carries a server path
(:func:`scrub_paths`).
"""

from __future__ import annotations

import asyncio
import logging
import re
from collections.abc import Awaitable, Callable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.jobs import JobNotFound, JobQuota, QueueFull
from service.mapstore import MapExists, MapInUse, MapNotFound
from service.npzcheck import MapRejected
from service.quotas import Busy, OverQuota
from service.schemas import FIELD_RANGES
from service.sessions import (
    InvalidSpec,
    SessionConflict,
    SessionLimit,
    SessionNotFound,
    SessionRefused,
)

log = logging.getLogger("omnisonar.service")


class ClientError(Exception):
    """A bad request value: status, field and allowed range go into the body."""

    def __init__(self, status: int, error: str, detail: str, field: str | None = None,
                 allowed: str | None = None, headers: dict[str, str] | None = None) -> None:
        super().__init__(detail)
        self.status, self.error, self.detail = status, error, detail
        self.field, self.allowed, self.headers = field, allowed, headers


#: An absolute path of two or more components (not "m/s", not a bare "/maps").
_ABS_PATH = re.compile(r"(?<![\w.~/])(?:/[^\s/'\"():,;]+){2,}/?")


def scrub_paths(text: str) -> str:
    """``text`` with every absolute file path cut to its last component."""
    return _ABS_PATH.sub(lambda m: m.group(0).rstrip("/").rsplit("/", 1)[-1], text)


def error_response(status: int, error: str, detail: str, field: str | None = None,
                   allowed: str | None = None, errors: list[dict[str, Any]] | None = None,
                   headers: dict[str, str] | None = None) -> JSONResponse:
    detail = scrub_paths(detail)
    allowed = None if allowed is None else scrub_paths(allowed)
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
               "list_type": "a list", "dict_type": "a JSON object",
               "int_type": "an integer (JSON number without fraction)",
               "float_type": "a number", "bool_type": "true or false (JSON boolean)",
               "value_error": "see detail"}


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

    @app.exception_handler(SessionRefused)
    async def _refused(_: Request, exc: SessionRefused) -> JSONResponse:
        return error_response(409, "map_changed", f"session {exc.session_id!r} was not "
                              f"restored: {exc}", "map_id",
                              "DELETE the session and start a new one on the current map")

    @app.exception_handler(MapRejected)
    async def _rejected(_: Request, exc: MapRejected) -> JSONResponse:
        return error_response(422, "validation", str(exc), exc.field, exc.allowed)

    @app.exception_handler(Busy)
    async def _busy(_: Request, exc: Busy) -> JSONResponse:
        return error_response(503, "busy", str(exc), None, None, headers={"Retry-After": "10"})

    @app.exception_handler(OverQuota)
    async def _over(_: Request, exc: OverQuota) -> JSONResponse:
        return error_response(429, "too_many_requests", str(exc), None, None,
                              headers={"Retry-After": "10"})

    @app.exception_handler(QueueFull)
    async def _queue_full(_: Request, exc: QueueFull) -> JSONResponse:
        return error_response(503, "busy", str(exc), None, None, headers={"Retry-After": "60"})

    @app.exception_handler(JobQuota)
    async def _job_quota(_: Request, exc: JobQuota) -> JSONResponse:
        return error_response(429, "too_many_jobs", str(exc), None, None,
                              headers={"Retry-After": "60"})

    @app.exception_handler(MapExists)
    async def _exists(_: Request, exc: MapExists) -> JSONResponse:
        return error_response(409, "conflict", f"map {exc.args[0]!r} exists; use overwrite",
                              "map_id")

    @app.exception_handler(MapInUse)
    async def _in_use(_: Request, exc: MapInUse) -> JSONResponse:
        return error_response(409, "in_use", str(exc), "map_id",
                              "a map no live session or running build uses")

    @app.exception_handler(SessionLimit)
    async def _limit(_: Request, exc: SessionLimit) -> JSONResponse:
        return error_response(429, "too_many_sessions", str(exc), None, None,
                              headers={"Retry-After": "10"})

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        if isinstance(exc, _BodyTooLarge):
            return error_response(413, "too_large", str(exc.detail), "body",
                                  f"<= {exc.limit} bytes")
        if isinstance(exc, _SlowBody):
            return error_response(408, "timeout", str(exc.detail), "body",
                                  f"the whole body within {exc.timeout_s:g} s",
                                  headers={"Connection": "close"})
        if exc.status_code == 405:
            allow = allowed_methods(request)
            return error_response(405, "method_not_allowed",
                                  f"{request.method} is not allowed here", "method",
                                  allow, headers={"Allow": allow})
        if exc.status_code == 400:
            return error_response(400, "bad_request", "the request body could not be parsed",
                                  "body", "UTF-8 JSON")
        return error_response(exc.status_code, "http", str(exc.detail),
                              headers=getattr(exc, "headers", None))

    @app.exception_handler(Exception)
    async def _bug(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return error_response(500, "internal", f"internal error ({type(exc).__name__})")


def allowed_methods(request: Request) -> str:
    """The methods the API documents on this request's path (the ``Allow`` of a 405): those
    of the most specific documented path (``/maps/build`` before ``/maps/{map_id}``)."""
    path = request.scope.get("path", "")
    hits = [(n, verbs) for pattern, n, verbs in _path_methods(request.app)
            if pattern.fullmatch(path)]
    fewest = min((n for n, _ in hits), default=0)
    methods = set().union(*(verbs for n, verbs in hits if n == fewest))
    return ", ".join(sorted(methods))


def _path_methods(app: Any) -> list[tuple[re.Pattern[str], int, set[str]]]:
    """(path regex, number of parameters, methods) of every path of the app's OpenAPI
    document (cached)."""
    cached: list[tuple[re.Pattern[str], int, set[str]]] | None = getattr(app.state, "_allow",
                                                                          None)
    if cached is None:
        cached = []
        for template, item in app.openapi().get("paths", {}).items():
            regex = re.sub(r"\\\{[^/]+?\\\}", "[^/]+", re.escape(template))
            cached.append((re.compile(regex), template.count("{"), {m.upper() for m in item}))
        app.state._allow = cached
    return cached


class BodyLimitMiddleware:
    """Answer 413 when a request body exceeds its limit (declared or streamed).

    ``limit_for(scope)`` gives the limit in bytes for a request; a body that is not complete
    ``timeout_for(scope)`` seconds after the handler first reads it is answered 408 and the
    connection closed (a slow client must not hold a worker; a deadline for the whole body,
    not per chunk, so a body trickling in a byte at a time is cut too).
    """

    def __init__(self, app: ASGIApp, limit_for: Callable[[Scope], int],
                 timeout_for: Callable[[Scope], float] | None = None) -> None:
        self.app = app
        self.limit_for = limit_for
        self.timeout_for = timeout_for

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
        timeout = None if self.timeout_for is None else self.timeout_for(scope)
        deadline: float | None = None  # the whole body by then, counted from the first read
        body_done = False

        async def limited_receive() -> Message:
            nonlocal seen, body_done, deadline
            if body_done:  # e.g. a streaming response waiting for a disconnect: no timeout
                return await receive()
            now = asyncio.get_running_loop().time()
            if timeout is not None and deadline is None:
                deadline = now + timeout
            try:
                msg = await asyncio.wait_for(receive(),
                                             None if deadline is None else max(0.0, deadline - now))
            except TimeoutError:
                raise _SlowBody(timeout or 0.0) from None
            body_done = msg["type"] != "http.request" or not msg.get("more_body", False)
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
        except _SlowBody as exc:
            if not started:
                resp = error_response(408, "timeout", str(exc.detail), "body",
                                      f"the whole body within {exc.timeout_s:g} s",
                                      headers={"Connection": "close"})
                await resp(scope, receive, send)


class _BodyTooLarge(StarletteHTTPException):
    """Raised from ``receive``; an HTTPException so FastAPI's body parsing re-raises it."""

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body over {limit} bytes")
        self.limit = limit


class _SlowBody(StarletteHTTPException):
    """Raised from ``receive`` when the client stalls mid-body."""

    def __init__(self, timeout_s: float) -> None:
        super().__init__(408, f"request body not received within {timeout_s:g} s")
        self.timeout_s = timeout_s


async def _send_413(scope: Scope, receive: Receive, send: Send, limit: int) -> None:
    resp = error_response(413, "too_large", f"request body over {limit} bytes", "body",
                          f"<= {limit} bytes")
    await resp(scope, receive, send)


Handler = Callable[[Request], Awaitable[Any]]
