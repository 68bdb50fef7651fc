"""Admission of concurrent work: a total cap and a cap per API key.

:class:`Gate` counts work in progress (e.g. map uploads being validated, each holding its
body and the decompressed arrays in memory). Entering a full gate raises at once instead of
queueing: :class:`Busy` (the server is full: 503) or :class:`OverQuota` (this key is: 429).
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager


class Busy(Exception):
    """The server-wide cap is reached (503, Retry-After)."""


class OverQuota(Exception):
    """This key's cap is reached (429, Retry-After)."""


class Gate:
    """At most ``total`` holders at once, and at most ``per_owner`` per owner."""

    def __init__(self, what: str, total: int, per_owner: int) -> None:
        self.what, self.total, self.per_owner = what, total, per_owner
        self._held: Counter[str] = Counter()
        self._lock = threading.Lock()

    @contextmanager
    def enter(self, owner: str) -> Iterator[None]:
        with self._lock:
            if sum(self._held.values()) >= self.total:
                raise Busy(f"{self.total} {self.what} in progress on the server; retry later")
            if self._held[owner] >= self.per_owner:
                raise OverQuota(f"{self.per_owner} {self.what} in progress for this key")
            self._held[owner] += 1
        try:
            yield
        finally:
            with self._lock:
                self._held[owner] -= 1
                if self._held[owner] <= 0:
                    del self._held[owner]
