"""A small HTTP client of the localization service: stream a run, print poses and errors.

    python -m service.client_example --url http://127.0.0.1:8000 RUN.npz [--global]

Each block of the run file is POSTed as raw little-endian float32 with its odometry in the
query parameters; the answer is the filter's pose. When the run carries tracked poses, the
error against them is printed too. This file is the README's client example; the demo
(``omnisonar demo-api``) uses :func:`stream_run`.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Iterator
from typing import Any

import httpx
import numpy as np

from mapping.angles import pose_error
from mapping.files import read_run
from mapping.run import Run


def open_session(http: httpx.Client, map_id: str, particles: int, seed: int,
                 initial_pose: tuple[float, float, float] | None,
                 wait_s: float = 300.0, beta: float | None = None,
                 sound_speed_m_s: float | None = None,
                 heights_m: tuple[float | None, float | None] = (None, None)) -> str:
    """``POST /sessions`` (retrying while the default map is still being built); ``beta``:
    the map's calibrated sensor sharpness, if any (``omnisonar calibrate``);
    ``sound_speed_m_s``: the air's, if not the map's; ``heights_m``: the sonar's and the
    ceiling's height, for the floor / ceiling copies of the echo model."""
    body: dict[str, Any] = {"map_id": map_id, "particles": particles, "seed": seed}
    if beta is not None:
        body["beta"] = beta
    if sound_speed_m_s is not None:
        body["sound_speed_m_s"] = sound_speed_m_s
    for key, value in zip(("sonar_height_m", "ceiling_height_m"), heights_m, strict=True):
        if value is not None:
            body[key] = value
    if initial_pose is None:
        body["global"] = True
    else:
        x, y, yaw = initial_pose
        body["initial_pose"] = {"x": x, "y": y, "yaw": yaw}
        body["initial_covariance"] = [[0.1**2, 0, 0], [0, 0.1**2, 0],
                                      [0, 0, math.radians(10) ** 2]]
    deadline = time.monotonic() + wait_s
    while True:
        r = http.post("/sessions", json=body)
        if r.status_code != 503 or time.monotonic() > deadline:
            r.raise_for_status()
            return str(r.json()["id"])
        time.sleep(float(r.headers.get("retry-after", "2")))


def stream_run(base_url: str, run: Run, map_id: str = "default", particles: int = 2000,
               seed: int = 0, initial_pose: tuple[float, float, float] | None = None,
               beta: float | None = None) -> Iterator[tuple[int, dict[str, Any], float]]:
    """Yield ``(block index, estimate JSON, round-trip seconds)`` for every block of ``run``."""
    with httpx.Client(base_url=base_url, timeout=60.0) as http:
        sid = open_session(http, map_id, particles, seed, initial_pose, beta=beta)
        try:
            for k in range(run.n_blocks):
                t0 = time.perf_counter()
                r = http.post(
                    f"/sessions/{sid}/blocks",
                    params={"seq": k, "fs_hz": run.config.fs_hz,
                            "speed_m_s": float(run.speed_m_s[k]),
                            "yaw_rate_rad_s": float(run.yaw_rate_rad_s[k])},
                    content=run.samples[k].astype("<f4").tobytes(),
                    headers={"content-type": "application/octet-stream"},
                )
                r.raise_for_status()
                yield k, r.json(), time.perf_counter() - t0
        finally:
            http.delete(f"/sessions/{sid}")


def pose_of(est: dict[str, Any]) -> np.ndarray:
    """``(x, y, yaw)`` of an estimate's JSON, for :func:`mapping.angles.pose_error`."""
    p = est["pose"]
    return np.array([p["x"], p["y"], p["yaw"]], dtype=np.float64)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", help="run file (.npz)")
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--map", default="default")
    ap.add_argument("--particles", type=int, default=2000)
    ap.add_argument("--global", dest="global_", action="store_true",
                    help="start globally instead of from the run's first tracked pose")
    args = ap.parse_args(argv)
    run = read_run(args.run)
    start = None if args.global_ else tuple(float(v) for v in run.pose[0])
    print(" seq       x       y     yaw   err_m  err_deg  conv")
    for k, est, _ in stream_run(args.url, run, args.map, args.particles,
                                initial_pose=start):  # type: ignore[arg-type]
        p = est["pose"]
        line = f"{k:4d} {p['x']:7.3f} {p['y']:7.3f} {p['yaw']:7.3f}"
        if np.all(np.isfinite(run.pose[k])):
            e_m, e_rad = pose_error(pose_of(est), run.pose[k])
            line += f" {e_m:7.3f} {math.degrees(e_rad):8.2f}"
        print(line + f"  {est['converged']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
