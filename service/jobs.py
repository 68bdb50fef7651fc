"""Background jobs (map builds): one worker thread, a bounded queue, a record per job.

A job is a function ``work(progress)`` where ``progress(fraction, message)`` reports how far
it got. The heavy lifting inside (e.g. :func:`mapping.build`) may itself use processes.

The queue holds at most ``max_queue`` jobs queued or running (:class:`QueueFull` beyond:
503 with Retry-After), and one owner at most ``max_per_owner`` of them (:class:`JobQuota`:
429). Records are kept in memory and, with a ``directory``, as ``<id>.json`` files written
atomically on every change of status (progress at most once a second): a restarted server
still answers for every job, and a job that was queued or running when the server died is
reported ``failed`` with the message :data:`INTERRUPTED`, never 404. The worker is a daemon
thread, so stopping the server does not wait for a running build (its map file is written
atomically: an interrupted build leaves no file behind).
"""

from __future__ import annotations

import json
import logging
import secrets
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import asdict, dataclass
from pathlib import Path
from queue import Queue
from typing import Any

from mapping.files import atomic_write_bytes

Progress = Callable[[float, str], None]
log = logging.getLogger("omnisonar.service")

#: Message of a job the server was stopped or killed during.
INTERRUPTED = "interrupted by a server restart; submit the build again"
_ACTIVE = ("queued", "running")


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
    owner: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class JobNotFound(KeyError):
    """No job with this id (404)."""


class QueueFull(Exception):
    """The build queue is full (503 with Retry-After)."""


class JobQuota(Exception):
    """This owner has as many builds queued or running as allowed (429)."""


class JobRunner:
    """Runs jobs one at a time on a background thread and keeps their records.

    Parameters
    ----------
    max_records : int
        Finished records kept (the oldest are pruned, with their files).
    directory : Path, optional
        Where records persist across restarts (None: memory only).
    max_queue : int, optional
        Jobs queued or running at once (None: unbounded).
    max_per_owner : int, optional
        Jobs queued or running per owner (None: unbounded).
    """

    def __init__(self, max_records: int = 200, directory: Path | None = None,
                 max_queue: int | None = None, max_per_owner: int | None = None) -> None:
        self._queue: Queue[tuple[JobRecord, Callable[[Progress], object], Future[None]] | None]
        self._queue = Queue()
        self._jobs: dict[str, JobRecord] = {}
        self._futures: dict[str, Future[None]] = {}
        self._lock = threading.Lock()
        self._max_records = max_records
        self.directory, self.max_queue, self.max_per_owner = directory, max_queue, max_per_owner
        self._saved_at: dict[str, float] = {}
        if directory is not None:
            directory.mkdir(parents=True, exist_ok=True)
            self._reload()
        self._worker = threading.Thread(target=self._loop, name="omnisonar-job", daemon=True)
        self._worker.start()

    def submit(self, kind: str, map_id: str, work: Callable[[Progress], object],
               owner: str = "") -> JobRecord:
        """Queue ``work``; ``QueueFull`` / ``JobQuota`` when the limits are reached."""
        rec = JobRecord(id=secrets.token_hex(6), kind=kind, map_id=map_id,
                        created_at=time.time(), owner=owner)
        with self._lock:
            active = [j for j in self._jobs.values() if j.status in _ACTIVE]
            if self.max_queue is not None and len(active) >= self.max_queue:
                raise QueueFull(f"{len(active)} builds queued or running; the queue holds "
                                f"{self.max_queue}")
            mine = sum(1 for j in active if j.owner == owner)
            if self.max_per_owner is not None and mine >= self.max_per_owner:
                raise JobQuota(f"{mine} builds queued or running for this key; "
                               f"max_jobs_per_key is {self.max_per_owner}")
            self._prune()
            self._jobs[rec.id] = rec
            fut: Future[None] = Future()
            self._futures[rec.id] = fut
        self._save(rec)
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
            self._save(rec, throttle_s=1.0)

        rec.status = "running"
        self._save(rec)
        try:
            work(progress)
        except Exception as exc:  # a failed job is a record, not a crash
            log.warning("job %s failed: %s: %s", rec.id, type(exc).__name__, exc)
            rec.status, rec.message = "failed", _public_message(exc)
        else:
            rec.status, rec.progress = "done", 1.0
        finally:
            rec.finished_at = time.time()
            self._save(rec)

    def get(self, job_id: str) -> JobRecord:
        with self._lock:
            try:
                return self._jobs[job_id]
            except KeyError:
                raise JobNotFound(job_id) from None

    def active_map_ids(self) -> list[str]:
        with self._lock:
            return sorted({j.map_id for j in self._jobs.values() if j.status in _ACTIVE})

    def wait(self, job_id: str, timeout_s: float | None = None) -> JobRecord:
        """Block until the job finished (for tests and the CLI)."""
        with self._lock:
            fut = self._futures[job_id]
        fut.result(timeout=timeout_s)
        return self.get(job_id)

    def shutdown(self) -> None:
        """Stop after the running job (queued ones are dropped: their records say
        :data:`INTERRUPTED`); does not wait."""
        while not self._queue.empty():
            item = self._queue.get_nowait()
            if item is not None:
                self._interrupt(item[0])
        self._queue.put(None)

    # -- persistence ----------------------------------------------------------------------
    def _interrupt(self, rec: JobRecord) -> None:
        rec.status, rec.message, rec.finished_at = "failed", INTERRUPTED, time.time()
        self._save(rec)

    def _save(self, rec: JobRecord, throttle_s: float = 0.0) -> None:
        if self.directory is None:
            return
        now = time.monotonic()
        if throttle_s and now - self._saved_at.get(rec.id, -1e9) < throttle_s:
            return
        self._saved_at[rec.id] = now
        try:
            atomic_write_bytes(self.directory / f"{rec.id}.json",
                               json.dumps(rec.to_dict()).encode(), fsync=False)
        except OSError as exc:  # a record that cannot be saved must not fail the build
            log.warning("could not save job record %s: %s", rec.id, exc)

    def _reload(self) -> None:
        assert self.directory is not None
        for path in sorted(self.directory.glob("*.json")):
            try:
                rec = JobRecord(**json.loads(path.read_text()))
            except (ValueError, TypeError) as exc:
                log.warning("skipped job record %s: %s", path.name, exc)
                continue
            self._jobs[rec.id] = rec
            if rec.status in _ACTIVE:  # the server died during it
                self._interrupt(rec)

    def _prune(self) -> None:
        done = [j for j in self._jobs.values() if j.finished_at is not None]
        for j in sorted(done, key=lambda j: j.created_at)[: max(0, len(self._jobs)
                                                                - self._max_records)]:
            self._jobs.pop(j.id, None)
            self._futures.pop(j.id, None)
            self._saved_at.pop(j.id, None)
            if self.directory is not None:
                (self.directory / f"{j.id}.json").unlink(missing_ok=True)


def _public_message(exc: Exception) -> str:
    """An exception as a job message a client may read: no server paths."""
    from service.errors import scrub_paths

    return scrub_paths(f"{type(exc).__name__}: {exc}")
