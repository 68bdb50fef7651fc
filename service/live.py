"""Watchers of live sessions: a per-key publish hook that costs nothing when nobody watches.

The session store (:class:`service.sessions.SessionStore`) owns one :class:`Broadcaster` and
calls :meth:`Broadcaster.publish` after each committed block of a watched session, in the
thread that ran the update and under the session's lock; :meth:`Broadcaster.watched` is the
only cost for a session nobody watches (one dict lookup, no lock). A watcher (the live view,
:mod:`service.routers.view`) therefore takes what it needs quickly and hands the rest to
its own thread or event loop. :meth:`Broadcaster.close` tells the watchers that a session
ended (published as ``None``).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

log = logging.getLogger("omnisonar.service")

#: A watcher: called with the published item, or ``None`` when the session ended.
Watcher = Callable[[Any], None]


class Broadcaster:
    """Watchers by key (a session id); thread-safe."""

    def __init__(self) -> None:
        self._watchers: dict[str, tuple[Watcher, ...]] = {}
        self._lock = threading.Lock()

    def watched(self, key: str) -> bool:
        """Does anyone watch ``key``? (A dict lookup: safe without the lock under the GIL.)"""
        return key in self._watchers

    def subscribe(self, key: str, watcher: Watcher) -> Callable[[], None]:
        """Call ``watcher`` on every item published for ``key``; returns the unsubscriber."""
        with self._lock:
            self._watchers[key] = (*self._watchers.get(key, ()), watcher)

        def unsubscribe() -> None:
            with self._lock:
                rest = tuple(w for w in self._watchers.get(key, ()) if w is not watcher)
                if rest:
                    self._watchers[key] = rest
                else:
                    self._watchers.pop(key, None)

        return unsubscribe

    def count(self, key: str) -> int:
        """How many watchers ``key`` has."""
        return len(self._watchers.get(key, ()))

    def publish(self, key: str, item: Any) -> None:
        """Hand ``item`` to each watcher of ``key`` (a watcher's exception is its own)."""
        for watcher in self._watchers.get(key, ()):
            try:
                watcher(item)
            except Exception:  # a broken watcher must not fail the update
                log.exception("live view watcher of %s failed", key)

    def close(self, key: str) -> None:
        """Tell ``key``'s watchers it ended (``None``) and drop them."""
        with self._lock:
            watchers = self._watchers.pop(key, ())
        for watcher in watchers:
            try:
                watcher(None)
            except Exception:
                log.exception("live view watcher of %s failed", key)
