"""Build jobs: bounded queue, per-key quota, records that survive a restart (issue 17)."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from pydantic import SecretStr

from service.app import create_app
from service.jobs import INTERRUPTED, JobQuota, JobRunner, QueueFull
from service.settings import Settings
from tests.service.helpers import map_file_bytes


def test_queue_is_bounded_and_per_owner(tmp_path: Path) -> None:
    release = threading.Event()
    jobs = JobRunner(directory=tmp_path, max_queue=3, max_per_owner=2)
    try:
        jobs.submit("build", "a", lambda p: release.wait(10), owner="k1")
        jobs.submit("build", "b", lambda p: None, owner="k1")
        with pytest.raises(JobQuota):
            jobs.submit("build", "c", lambda p: None, owner="k1")
        jobs.submit("build", "c", lambda p: None, owner="k2")
        with pytest.raises(QueueFull):
            jobs.submit("build", "d", lambda p: None, owner="k3")
    finally:
        release.set()
        jobs.shutdown()


def test_job_after_restart_is_reported_not_404(tmp_path: Path) -> None:
    release = threading.Event()
    jobs = JobRunner(directory=tmp_path)
    running = jobs.submit("build", "a", lambda p: release.wait(10))
    queued = jobs.submit("build", "b", lambda p: None)
    done_dir = tmp_path / "done"
    finished = JobRunner(directory=done_dir)
    ok = finished.submit("build", "c", lambda p: p(0.5, "half"))
    finished.wait(ok.id, 10)
    deadline = time.monotonic() + 5
    while jobs.get(running.id).status != "running" and time.monotonic() < deadline:
        time.sleep(0.01)
    # the process dies here (no shutdown): a new runner reads the records
    again = JobRunner(directory=tmp_path)
    for rec in (again.get(running.id), again.get(queued.id)):
        assert rec.status == "failed" and rec.message == INTERRUPTED
        assert rec.finished_at is not None
    assert JobRunner(directory=done_dir).get(ok.id).status == "done"
    release.set()
    jobs.shutdown()
    again.shutdown()


def test_job_failure_message_has_no_server_path(tmp_path: Path) -> None:
    jobs = JobRunner(directory=tmp_path)

    def work(_: object) -> None:
        raise ValueError(f"{tmp_path}/runs/r1.npz: not a readable .npz run file")

    rec = jobs.submit("build", "a", work)  # type: ignore[arg-type]
    assert jobs.wait(rec.id, 10).status == "failed"
    assert str(tmp_path) not in jobs.get(rec.id).message
    assert "r1.npz" in jobs.get(rec.id).message
    jobs.shutdown()


def test_http_job_record_survives_restart(tmp_path: Path) -> None:
    maps = tmp_path / "maps"
    maps.mkdir()
    (maps / "room.npz").write_bytes(map_file_bytes())
    cfg = Settings(maps_dir=maps, default_map=False, max_build_queue=1)
    jobs_dir = cfg.jobs_path
    jobs_dir.mkdir(parents=True)
    (jobs_dir / "abc123.json").write_text(
        '{"id": "abc123", "kind": "build", "map_id": "m", "status": "running", '
        '"progress": 0.3, "message": "", "created_at": 1.0, "finished_at": null, "owner": ""}')
    with TestClient(create_app(cfg)) as c:
        job = c.get("/jobs/abc123").json()
        assert job["status"] == "failed" and job["message"] == INTERRUPTED


def test_http_build_queue_is_bounded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The issue's '51 build requests accepted in a row': over HTTP the queue takes
    ``max_build_queue`` builds (503 + Retry-After beyond) and ``max_jobs_per_key`` per key
    (429 + Retry-After); a slot frees when a build ends."""
    from service import builds

    release = threading.Event()
    monkeypatch.setattr(builds, "build_to_store", lambda *a, **k: release.wait(30))
    maps = tmp_path / "maps"
    maps.mkdir()
    cfg = Settings(maps_dir=maps, default_map=False, max_build_queue=3, max_jobs_per_key=2,
                   api_keys=SecretStr("u"), admin_keys=SecretStr("a1,a2"))
    (cfg.runs_path).mkdir(parents=True)
    (cfg.runs_path / "r.npz").write_bytes(b"a run (never read: the build is stubbed)")
    try:
        with TestClient(create_app(cfg)) as c:
            def build(key: str, map_id: str) -> Any:
                return c.post("/maps/build", json={"runs": ["r"], "map_id": map_id},
                              headers={"Authorization": f"Bearer {key}"})

            assert [build("a1", f"m{i}").status_code for i in range(2)] == [202, 202]
            over = build("a1", "m2")
            assert over.status_code == 429 and over.headers["retry-after"], over.text
            assert build("a2", "m3").status_code == 202
            full = build("a2", "m4")
            assert full.status_code == 503 and full.headers["retry-after"], full.text
            assert full.json()["error"] == "busy"
            busy = c.delete("/maps/m0", headers={"Authorization": "Bearer a1"})
            assert busy.status_code == 409 and busy.json()["error"] == "in_use"  # being built
            release.set()  # the builds end: the queue takes new ones again
            deadline, status = time.monotonic() + 10, 0
            while time.monotonic() < deadline and status != 202:
                status = build("a2", "m5").status_code
                time.sleep(0.05)
            assert status == 202
    finally:
        release.set()
