"""The live view in a real headless Chromium: the page loads, draws the session, and updates
after a POSTed block (issue 17 item 7).

The service runs under uvicorn in a thread on a free loopback port, with the real filter on
the paper scene (walls rasterized at 5 cm, the scene's walls as the map's walls) and a short
simulated run. Chromium is Debian's ``/usr/bin/chromium`` driven by Playwright (no browser
download). Without Chromium or Playwright the test is skipped, unless
``OMNISONAR_REQUIRE_BROWSER=1`` (set by ``.ci/run``): then it fails, so CI never skips it
silently. The screenshot goes to ``$OMNISONAR_SCREENSHOT_DIR/live_view.png`` (the one in
``docs/img/`` was made so) or to the test's temporary directory.
"""

from __future__ import annotations

import os
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from mapping.files import write_map
from mapping.run import Run
from mapping.scene import builtin_scene
from mapping.wallmap import WallMap
from service.builds import simulate_default_run
from service.server import free_port
from service.settings import Settings
from tests.service.helpers import raster_map

CHROMIUM = os.environ.get("OMNISONAR_CHROMIUM", "/usr/bin/chromium")
REQUIRED = os.environ.get("OMNISONAR_REQUIRE_BROWSER", "") not in ("", "0")
#: Flags that work in a container as root, offline (no sandbox, GPU, QUIC or phoning home).
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
N_BLOCKS = 3


def _browser_or_skip() -> None:
    reason = None
    if shutil.which(CHROMIUM) is None:
        reason = f"no Chromium at {CHROMIUM} (apt-get install chromium)"
    else:
        try:
            import playwright.sync_api  # noqa: F401
        except ImportError:
            reason = "playwright is not installed (pip install -e '.[dev]')"
    if reason is not None:
        if REQUIRED:
            pytest.fail(f"OMNISONAR_REQUIRE_BROWSER is set but {reason}")
        pytest.skip(reason)


@pytest.fixture(scope="module")
def run() -> Run:
    return simulate_default_run("paper-a", seed=7, n_blocks=N_BLOCKS)


@pytest.fixture()
def server(tmp_path: Path) -> Iterator[str]:
    """The app under uvicorn in a thread, on a free 127.0.0.1 port; yields its URL."""
    import uvicorn

    from service.app import create_app

    segs = builtin_scene("paper").segments().reshape(-1, 4)
    g = raster_map("paper")
    wallmap = WallMap(G=g.G, origin_m=g.origin_m, resolution_m=g.resolution_m, sonar=g.sonar,
                      method=g.method, provenance=g.provenance, walls_m=segs)
    write_map(tmp_path / "maps" / "paper.npz", wallmap)
    cfg = Settings(maps_dir=tmp_path / "maps", sessions_dir=tmp_path / "sessions",
                   default_map=False)
    port = free_port()
    srv = uvicorn.Server(uvicorn.Config(create_app(cfg), host="127.0.0.1", port=port,
                                        log_level="warning"))
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not srv.started:
        assert time.monotonic() < deadline and thread.is_alive(), "uvicorn did not start"
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        srv.should_exit = True
        thread.join(15)


def _post_block(http: httpx.Client, sid: str, run: Run, k: int) -> None:
    r = http.post(f"/sessions/{sid}/blocks",
                  params={"seq": k, "fs_hz": run.config.fs_hz,
                          "speed_m_s": float(run.speed_m_s[k]),
                          "yaw_rate_rad_s": float(run.yaw_rate_rad_s[k])},
                  content=run.samples[k].astype("<f4").tobytes(),
                  headers={"content-type": "application/octet-stream"})
    assert r.status_code == 200, r.text


@pytest.mark.slow
def test_live_view_updates_in_chromium(server: str, run: Run, tmp_path: Path) -> None:
    _browser_or_skip()
    from playwright.sync_api import sync_playwright

    x, y, yaw = (float(v) for v in run.pose[0])
    with httpx.Client(base_url=server, timeout=60) as http:
        r = http.post("/sessions", json={"map_id": "paper", "particles": 1000, "seed": 5,
                                         "initial_pose": {"x": x, "y": y, "yaw": yaw}})
        assert r.status_code == 201, r.text
        sid = r.json()["id"]
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
            try:
                page = browser.new_page(viewport={"width": 1340, "height": 720})
                errors: list[str] = []
                page.on("pageerror", lambda exc: errors.append(str(exc)))
                page.goto(f"{server}/sessions/{sid}/view")
                # the page connected and drew the session as it is (no block yet)
                page.wait_for_function("document.body.dataset.state === 'live' && "
                                       "document.body.dataset.frames === '1'", timeout=20_000)
                assert page.get_attribute("body", "data-seq") == ""
                assert page.inner_text("#status") == "no block yet"
                for k in range(N_BLOCKS):
                    _post_block(http, sid, run, k)
                    # the POSTed block reaches the page without a reload
                    page.wait_for_function(f"document.body.dataset.seq === '{k}'",
                                           timeout=20_000)
                body = page.locator("body")
                assert body.get_attribute("data-updates") == str(N_BLOCKS)
                status = body.get_attribute("data-status")
                assert status in ("converged", "uncertain", "lost")
                assert page.inner_text("#status") == status
                assert page.inner_text("#f-seq") == str(N_BLOCKS - 1)
                assert page.inner_text("#f-pose").endswith(" m")
                # the canvases carry drawings: the heat map is not blank
                lit = page.evaluate(
                    "(() => { const c = document.getElementById('heat');"
                    " const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
                    " let n = 0; for (let i = 0; i < d.length; i += 4) n += d[i] > 0; return n;"
                    " })()")
                assert lit > 10_000
                out = Path(os.environ.get("OMNISONAR_SCREENSHOT_DIR", str(tmp_path)))
                out.mkdir(parents=True, exist_ok=True)
                page.screenshot(path=str(out / "live_view.png"))
                assert (out / "live_view.png").stat().st_size > 10_000
                # deleting the session ends the stream; the page says so
                assert http.delete(f"/sessions/{sid}").status_code == 204
                page.wait_for_function("document.body.dataset.state === 'ended'",
                                       timeout=10_000)
                assert errors == []
            finally:
                browser.close()
