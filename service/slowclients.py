"""Uvicorn settings against slow and idle clients.

Uvicorn closes an idle keep-alive connection after ``timeout_keep_alive`` but has no limit
on how long a client may take to send a request's *headers*: each byte resets its timer, so
half-sent requests hold connections for ever. :class:`HeaderDeadlineH11` gives every request
``read_timeout_s`` from the moment the connection can carry a new one (opened, or the last
response sent) until its headers are complete, then closes the connection (bytes arriving
do not extend it). The body has the same budget, for the whole body, in
:class:`service.errors.BodyLimitMiddleware` (408).
:func:`uvicorn_options` gathers these with uvicorn's own limits (keep-alive, concurrency,
header size).
"""

from __future__ import annotations

import asyncio
from typing import Any

from uvicorn.protocols.http.h11_impl import H11Protocol

from service.settings import Settings

#: Largest request head (request line + headers) h11 buffers, bytes.
MAX_HEAD_BYTES = 16 * 1024


class HeaderDeadlineH11(H11Protocol):
    """uvicorn's h11 protocol with a deadline for each request's headers."""

    header_timeout_s = 30.0

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._arm()

    def connection_lost(self, exc: Exception | None) -> None:
        deadline = getattr(self, "_deadline", None)
        if deadline is not None:
            deadline.cancel()
        super().connection_lost(exc)

    def _arm(self) -> None:
        old = getattr(self, "_deadline", None)
        if old is not None:
            old.cancel()
        waiting_after = self.cycle  # a new request replaces the cycle
        self._deadline = self.loop.call_later(self.header_timeout_s, self._expire,
                                              waiting_after)

    def _expire(self, waiting_after: object) -> None:
        if self.cycle is waiting_after and not self.transport.is_closing():
            self.transport.close()  # no complete request head in time


def uvicorn_options(cfg: Settings) -> dict[str, Any]:
    """Keyword arguments of ``uvicorn.run`` bounding what slow or many clients can hold."""
    protocol = type("HeaderDeadline", (HeaderDeadlineH11,),
                    {"header_timeout_s": float(cfg.read_timeout_s)})
    return {
        "http": protocol,
        "timeout_keep_alive": max(1, round(cfg.keep_alive_s)),
        "limit_concurrency": cfg.max_connections,
        "h11_max_incomplete_event_size": MAX_HEAD_BYTES,
        "timeout_graceful_shutdown": 5,
    }
