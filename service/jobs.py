"""Background jobs (map builds): one worker thread, a job record with progress per job.

A job is a function ``work(progress)`` where ``progress(fraction, message)`` reports how far
it got. The heavy lifting inside (e.g. :func:`mapping.build`) may itself use processes.
Jobs live in memory: a restarted server forgets finished jobs (their maps are on disk).
The worker is a daemon thread, so stopping the server does not wait for a running build
(its map file is written atomically: an interrupted build leaves no file behind).
"""

from __future__ import annotations

import secrets
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import asdict, dataclass
from queue import Queue
from typing import Any

Progress = Callable[[float, str], None]


@dataclass
class JobRecord:
    id: str
    kind: str
    map_id: str
    status: str = "queued"
    progress: float = 0.0
    message: str = ""
    created_at: float = 0.0
    finished_at: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class JobNotFound(KeyError):
    """No job with this id (404)."""


class JobRunner:
    """Runs jobs one at a time on a background thread and keeps their records."""

    def __init__(self, max_records: int = 200) -> None:
        self._queue: Queue[tuple[JobRecord, Callable[[Progress], object], Future[None]] | None]
        self._queue = Queue()
        self._worker = threading.Thread(target=self._loop, name="omnisonar-job", daemon=True)
        self._worker.start()
        self._jobs: dict[str, JobRecord] = {}
        self._futures: dict[str, Future[None]] = {}
        self._lock = threading.Lock()
        self._max_records = max_records

    def submit(self, kind: str, map_id: str, work: Callable[[Progress], object]) -> JobRecord:
        rec = JobRecord(id=secrets.token_hex(6), kind=kind, map_id=map_id,
                        created_at=time.time())
        with self._lock:
            self._prune()
            self._jobs[rec.id] = rec
            fut: Future[None] = Future()
            self._futures[rec.id] = fut
        self._queue.put((rec, work, fut))
        return rec

    def _loop(self) -> None:
        while (item := self._queue.get()) is not None:
            rec, work, fut = item
            self._run(rec, work)
            fut.set_result(None)

    def _run(self, rec: JobRecord, work: Callable[[Progress], object]) -> None:
        def progress(fraction: float, message: str = "") -> None:
            rec.progress = min(1.0, max(0.0, float(fraction)))
            rec.message = message

        rec.status = "running"
        try:
            work(progress)
        except Exception as exc:  # a failed job is a record, not a crash
            rec.status, rec.message = "failed", f"{type(exc).__name__}: {exc}"
        else:
            rec.status, rec.progress = "done", 1.0
        finally:
            rec.finished_at = time.time()

    def get(self, job_id: str) -> JobRecord:
        with self._lock:
            try:
                return self._jobs[job_id]
            except KeyError:
                raise JobNotFound(job_id) from None

    def active_map_ids(self) -> list[str]:
        with self._lock:
            return sorted({j.map_id for j in self._jobs.values()
                           if j.status in ("queued", "running")})

    def wait(self, job_id: str, timeout_s: float | None = None) -> JobRecord:
        """Block until the job finished (for tests and the CLI)."""
        with self._lock:
            fut = self._futures[job_id]
        fut.result(timeout=timeout_s)
        return self.get(job_id)

    def shutdown(self) -> None:
        """Stop after the running job (queued ones are dropped); does not wait."""
        while not self._queue.empty():
            self._queue.get_nowait()
        self._queue.put(None)

    def _prune(self) -> None:
        done = [j for j in self._jobs.values() if j.finished_at is not None]
        for j in sorted(done, key=lambda j: j.created_at)[: max(0, len(self._jobs)
                                                                - self._max_records)]:
            self._jobs.pop(j.id, None)
            self._futures.pop(j.id, None)
