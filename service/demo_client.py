"""The main job through the HTTP API (``omnisonar demo-api``).

Start the service as a child process, wait for its default map (the paper scene, built on
first start and cached), calibrate the map's sensor sharpness on one tracked drive
(:func:`localization.calibration.calibrate_beta`, as ``omnisonar calibrate`` does), stream a
held-out simulated run of the same scene along another path with another noise seed in a
session with that beta, print the pose track against the truth (with the NEES of the
reported covariance), stop the service.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from localization.estimate import nees
from mapping.angles import pose_error
from service.builds import simulate_default_run
from service.client_example import pose_of, stream_run
from service.jsonout import strict_json
from service.server import ServerProcess

HELD_OUT_PATH = "paper-a"
HELD_OUT_SEED = 7
#: The calibration drive: the same route as the held-out run, another noise seed.
CALIBRATION_SEED = 8
CALIBRATION_BETAS = (50.0, 100.0, 200.0, 400.0)


def calibrate_map(map_path: Path, n_blocks: int | None) -> float:
    """The sharpness whose NEES is 3 on a simulated tracked drive on the map at ``map_path``."""
    from localization.calibration import CalibrationRun, calibrate_beta
    from localization.particle_filter import FilterConfig
    from localization.sensor import SensorConfig, build_tables
    from mapping.files import read_map

    drive = simulate_default_run(HELD_OUT_PATH, seed=CALIBRATION_SEED, n_blocks=n_blocks)
    tables = build_tables(read_map(map_path), SensorConfig())
    cal = calibrate_beta(tables, [CalibrationRun.from_run(drive, tables.config)], CALIBRATION_BETAS,
                         FilterConfig(n_particles=1000), np.random.default_rng(0), n_seeds=1)
    table = ", ".join(f"{b:g}: {q:.1f}" for b, q in zip(cal.betas, cal.nees_mean, strict=True))
    print(f"calibration drive ({HELD_OUT_PATH}, seed {CALIBRATION_SEED}): mean NEES per beta "
          f"{table} -> beta {cal.beta:.0f}")
    return cal.beta


def wait_for_map(url: str, map_id: str, timeout_s: float = 600.0) -> dict[str, Any]:
    """Poll ``GET /maps/{id}`` until the map exists; prints build progress."""
    deadline = time.monotonic() + timeout_s
    last = ""
    while time.monotonic() < deadline:
        r = httpx.get(f"{url}/maps/{map_id}", timeout=10)
        if r.status_code == 200:
            return dict(r.json())
        building = httpx.get(f"{url}/maps", timeout=10).json()["building"]
        if map_id not in building:
            raise RuntimeError(f"map {map_id!r} is neither stored nor being built")
        if last != "waiting":
            print(f"waiting for map {map_id!r} (built on first start) ...", flush=True)
            last = "waiting"
        time.sleep(1.0)
    raise RuntimeError(f"map {map_id!r} not ready after {timeout_s} s")


def run_demo(work_dir: Path, n_blocks: int | None = None, particles: int = 2000,
             global_init: bool = False, seed: int = 0) -> dict[str, Any]:
    """Run the demo; returns the summary it prints (and writes ``track.json``)."""
    work_dir.mkdir(parents=True, exist_ok=True)
    env = {"OMNISONAR_SESSIONS_DIR": str(work_dir / "sessions")}
    with ServerProcess(work_dir / "maps", env=env, log_path=work_dir / "server.log") as srv:
        print(f"service up at {srv.url} (pid {srv.pid})")
        info = wait_for_map(srv.url, "default")
        print(f"map 'default': {info['shape'][1]} x {info['shape'][0]} cells at "
              f"{info['resolution_m'] * 1000:.0f} mm, method {info['method']}")
        png = httpx.get(f"{srv.url}/maps/default/image.png", timeout=60)
        png.raise_for_status()
        (work_dir / "map.png").write_bytes(png.content)
        print(f"wrote {work_dir / 'map.png'} (GET /maps/default/image.png)")
        beta = calibrate_map(work_dir / "maps" / "default.npz", n_blocks)
        run = simulate_default_run(HELD_OUT_PATH, seed=HELD_OUT_SEED, n_blocks=n_blocks)
        print(f"held-out run: path {HELD_OUT_PATH}, noise seed {HELD_OUT_SEED}, "
              f"{run.n_blocks} blocks; init {'global' if global_init else 'tracked'}")
        start = None if global_init else tuple(float(v) for v in run.pose[0])
        print(" seq   true x  true y  true yaw |   est x   est y  est yaw |  err_m  err_deg"
              "  conv  ms")
        rows = []
        for k, est, rtt in stream_run(srv.url, run, "default", particles, seed,
                                      start, beta):  # type: ignore[arg-type]
            e_m, e_rad = pose_error(pose_of(est), run.pose[k])
            e_deg = math.degrees(e_rad)
            t, p = run.pose[k], est["pose"]
            print(f"{k:4d} {t[0]:8.3f} {t[1]:7.3f} {math.degrees(t[2]):9.1f} | "
                  f"{p['x']:7.3f} {p['y']:7.3f} {math.degrees(p['yaw']):8.1f} | "
                  f"{e_m:6.3f} {e_deg:8.2f}  {'yes' if est['converged'] else ' no'} "
                  f"{1e3 * rtt:4.0f}", flush=True)
            rows.append({"seq": k, "truth": t.tolist(), "estimate": est, "err_m": e_m,
                         "err_deg": e_deg, "rtt_s": rtt,
                         "nees": nees(pose_of(est), np.asarray(est["covariance"]),
                                      run.pose[k])})
    summary = {**summarize(rows), "beta": beta}
    (work_dir / "track.json").write_text(strict_json({"summary": summary, "track": rows}))
    print(strict_json(summary, indent=1))
    return summary


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """RMSE and mean NEES after the first converged block, share within 10 cm, latency."""
    conv = [i for i, r in enumerate(rows) if r["estimate"]["converged"]]
    after = rows[conv[0]:] if conv else []
    e_m = np.array([r["err_m"] for r in after])
    e_deg = np.array([r["err_deg"] for r in after])
    rtt = np.array([r["rtt_s"] for r in rows])
    return {
        "blocks": len(rows),
        "first_converged_block": conv[0] if conv else None,
        "position_rmse_m": float(np.sqrt(np.mean(e_m**2))) if e_m.size else None,
        "heading_rmse_deg": float(np.sqrt(np.mean(e_deg**2))) if e_deg.size else None,
        "share_within_10cm": float(np.mean([r["err_m"] <= 0.10 for r in rows])),
        "final_err_m": rows[-1]["err_m"] if rows else None,
        "nees_mean": float(np.mean([r["nees"] for r in after])) if after else None,
        "latency_p50_ms": float(1e3 * np.median(rtt)) if rtt.size else None,
    }
