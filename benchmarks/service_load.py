"""Load on the localization service: a local uvicorn, clients streaming blocks over HTTP.

Each client owns a session at 2,000 particles on the paper scene (walls rasterized at 5 cm)
and streams blocks of a simulated run (``paper-a``, 0 dB per-sample noise, cycled).

(a) paced: clients send at 10x real time (one block every 102.3 ms), and 8 clients at real
    time (one block every 1.023 s): errors, p50/p95 latency per block, server RSS before and
    after.
(b) saturation: clients back to back: blocks per second served and p95 latency, against the
    cost of one update measured in this process (block -> heat map -> filter step), i.e.
    how close the HTTP layer gets to the compute bound.

Writes ``benchmarks/results/service_load.json`` and ``service_load.png``. Keep it < 3 min.
The issue asks for 8 clients x 200 blocks at 10x real time; one update costs tens of ms on
this shared 2-core machine, so 8 clients at 10x (80 blocks/s) are far beyond the compute
bound: (a) is scaled down to what 2 cores can serve, and the 8-client case runs at 1x.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import matplotlib
import matplotlib.ticker
import numpy as np

# a script run from benchmarks/ must not shadow the packages: import from the repository root
from matplotlib import pyplot as plt

from mapping.files import write_map
from mapping.run import Run
from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from mapping.wallmap import WallMap
from service.builds import simulate_default_run
from service.localizer import LocalizationFactory
from service.mapstore import MapStore
from service.server import ServerProcess, rss_bytes
from service.sessions import BlockInput, FilterSpec, Session, write_checkpoint

_HERE = Path(__file__).resolve().parent
matplotlib.use("Agg")

OUT = Path(__file__).parent / "results"
PARTICLES = 2000
RUN_BLOCKS = 16


def raster_map(scene: str = "paper", res: float = 0.05, margin: float = 0.3) -> WallMap:
    """G = 1 on the cells crossed by the scene's walls."""
    segs = builtin_scene(scene).segments().reshape(-1, 4)
    x0, y0 = segs[:, [0, 2]].min() - margin, segs[:, [1, 3]].min() - margin
    nx = int(round((segs[:, [0, 2]].max() + margin - x0) / res)) + 1
    ny = int(round((segs[:, [1, 3]].max() + margin - y0) / res)) + 1
    G = np.zeros((ny, nx))
    for xa, ya, xb, yb in segs:
        t = np.linspace(0, 1, int(math.hypot(xb - xa, yb - ya) / (res / 4)) + 2)
        G[np.rint((ya + t * (yb - ya) - y0) / res).astype(int),
          np.rint((xa + t * (xb - xa) - x0) / res).astype(int)] = 1.0
    return WallMap(G=G, origin_m=(x0, y0), resolution_m=res, sonar=SonarConfig().to_json(),
                   method="raster")


def in_process_update_ms(maps: MapStore, run: Run, ckpt: Path,
                         n: int = 24) -> dict[str, float]:
    """Median/p95 ms of one tracker update (heat map + filter step) without HTTP, and of
    the checkpoint the service writes after it (npz + fsync + rename)."""
    fac = LocalizationFactory(maps)
    spec = FilterSpec(particles=PARTICLES, seed=0,
                      initial_pose=tuple(run.pose[0]))  # type: ignore[arg-type]
    tr = fac.create("paper", spec)
    session = Session(id="bench", map_id="paper", spec=spec, tracker=tr, created_at=0.0,
                      last_active_at=0.0)
    times, ck, ck_nosync = [], [], []
    for i in range(n + 3):
        k = i % run.n_blocks
        blk = BlockInput(seq=i, samples=run.samples[k].astype(np.float64),
                         speed_m_s=float(run.speed_m_s[k]),
                         yaw_rate_rad_s=float(run.yaw_rate_rad_s[k]),
                         dt_s=0.0 if i == 0 else run.config.block_s)
        t0 = time.perf_counter()
        tr.update(blk)
        t1 = time.perf_counter()
        write_checkpoint(ckpt, session)
        t2 = time.perf_counter()
        write_checkpoint(ckpt, session, fsync=False)
        if i >= 3:  # warm-up: numba cache load, FFT plans
            times.append(1e3 * (t1 - t0))
            ck.append(1e3 * (t2 - t1))
            ck_nosync.append(1e3 * (time.perf_counter() - t2))
    return {"median_ms": float(np.median(times)), "p95_ms": float(np.percentile(times, 95)),
            "checkpoint_median_ms": float(np.median(ck)),
            "checkpoint_no_fsync_median_ms": float(np.median(ck_nosync))}


def client(url: str, run: Run, n_blocks: int, period_s: float, out: dict[str, Any]) -> None:
    """One session; ``n_blocks`` blocks, one every ``period_s`` (0: back to back)."""
    lat, errors = [], 0
    x, y, yaw = (float(v) for v in run.pose[0])
    with httpx.Client(base_url=url, timeout=60) as http:
        sid = http.post("/sessions", json={"map_id": "paper", "particles": PARTICLES,
                                           "initial_pose": {"x": x, "y": y, "yaw": yaw}}
                        ).json()["id"]
        t_start = time.perf_counter()
        for i in range(n_blocks):
            wait = t_start + i * period_s - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            k = i % run.n_blocks
            t0 = time.perf_counter()
            r = http.post(f"/sessions/{sid}/blocks",
                          params={"seq": i, "fs_hz": 40000.0,
                                  "speed_m_s": float(run.speed_m_s[k]),
                                  "yaw_rate_rad_s": float(run.yaw_rate_rad_s[k])},
                          content=run.samples[k].astype("<f4").tobytes(),
                          headers={"content-type": "application/octet-stream"})
            lat.append(time.perf_counter() - t0)
            errors += r.status_code != 200
        out["wall_s"] = time.perf_counter() - t_start
        http.delete(f"/sessions/{sid}")
    out["latency_s"], out["errors"] = lat, errors


def load(url: str, pid: int, run: Run, n_clients: int, n_blocks: int,
         period_s: float) -> dict[str, Any]:
    rss0 = rss_bytes(pid)
    outs: list[dict[str, Any]] = [{} for _ in range(n_clients)]
    threads = [threading.Thread(target=client, args=(url, run, n_blocks, period_s, o))
               for o in outs]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    lat = 1e3 * np.concatenate([o["latency_s"] for o in outs])
    return {
        "clients": n_clients, "blocks_per_client": n_blocks, "period_s": period_s,
        "errors": int(sum(o["errors"] for o in outs)),
        "p50_ms": float(np.percentile(lat, 50)), "p95_ms": float(np.percentile(lat, 95)),
        "max_ms": float(lat.max()), "blocks_per_s": float(lat.size / wall),
        "rss_before_mb": rss0 / 2**20, "rss_after_mb": rss_bytes(pid) / 2**20,
        "latencies_ms": lat.tolist(),
    }


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    cfg = SonarConfig()
    with tempfile.TemporaryDirectory() as tmp:
        maps_dir = Path(tmp) / "maps"
        write_map(maps_dir / "paper.npz", raster_map())
        run = simulate_default_run("paper-a", seed=7, n_blocks=RUN_BLOCKS)
        base = in_process_update_ms(MapStore(maps_dir), run, Path(tmp) / "ckpt.npz")
        print(f"in-process update at {PARTICLES} particles: median {base['median_ms']:.1f} ms, "
              f"p95 {base['p95_ms']:.1f} ms; checkpoint {base['checkpoint_median_ms']:.1f} ms "
              f"(without fsync {base['checkpoint_no_fsync_median_ms']:.1f} ms)",
              flush=True)
        env = {"OMNISONAR_DEFAULT_MAP": "false", "OMNISONAR_SESSIONS_DIR": f"{tmp}/sessions"}
        with ServerProcess(maps_dir, env=env) as srv:
            load(srv.url, srv.pid, run, 1, 5, 0.0)  # warm-up (tables, numba cache)
            cases = {
                "paced_10x_1client": load(srv.url, srv.pid, run, 1, 60, cfg.block_s / 10),
                "paced_10x_2clients": load(srv.url, srv.pid, run, 2, 60, cfg.block_s / 10),
                "paced_1x_8clients": load(srv.url, srv.pid, run, 8, 12, cfg.block_s),
                "saturation_4clients": load(srv.url, srv.pid, run, 4, 25, 0.0),
            }
    for name, c in cases.items():
        print(f"{name:22s} errors {c['errors']}  p50 {c['p50_ms']:6.1f} ms  p95 "
              f"{c['p95_ms']:6.1f} ms  {c['blocks_per_s']:5.1f} blocks/s  RSS "
              f"{c['rss_before_mb']:.0f} -> {c['rss_after_mb']:.0f} MB", flush=True)
    cores = os.cpu_count() or 1
    bound = 1e3 / (base["median_ms"] + base["checkpoint_median_ms"])
    sat = cases["saturation_4clients"]["blocks_per_s"]
    summary = {
        "particles": PARTICLES, "cores": cores, "in_process_update": base,
        "compute_bound_blocks_per_s_one_core": bound,
        "compute_bound_blocks_per_s_all_cores": bound * cores,
        "saturation_vs_one_core_bound": sat / bound,
        "saturation_vs_all_cores_bound": sat / (bound * cores),
        "load_average_1min": os.getloadavg()[0],
        "note": (f"8 clients x 200 blocks at 10x real time need 80 blocks/s; this machine "
                 f"saturates at {sat:.0f} blocks/s through HTTP (filter compute bound "
                 f"{bound * cores:.0f}/s), so (a) runs 1-2 clients at 10x and 8 clients at 1x"),
        "cases": {k: {kk: vv for kk, vv in v.items() if kk != "latencies_ms"}
                  for k, v in cases.items()},
    }
    print(f"saturation {sat:.1f} blocks/s vs update+checkpoint bound {bound:.1f}/s per core "
          f"({cores} cores): {100 * sat / (bound * cores):.0f} % of the all-core bound")
    (OUT / "service_load.json").write_text(json.dumps(summary, indent=1))
    plot(cases, base, OUT / "service_load.png")


def plot(cases: dict[str, Any], base: dict[str, float], path: Path) -> None:
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    for name, c in cases.items():
        lat = np.sort(c["latencies_ms"])
        ax1.plot(lat, np.arange(1, lat.size + 1) / lat.size, label=name)
    ax1.axvline(base["median_ms"], color="k", ls="--", label="in-process update (median)")
    ax1.set_xlabel("latency per block (ms)")
    ax1.set_ylabel("CDF")
    ax1.set_xscale("log")
    ax1.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax1.legend(fontsize=7)
    names = list(cases)
    ax2.bar(range(len(names)), [cases[n]["blocks_per_s"] for n in names])
    ax2.axhline(1e3 / (base["median_ms"] + base["checkpoint_median_ms"]) * (os.cpu_count() or 1),
                color="r", ls="--", label="update + checkpoint bound, all cores")
    ax2.set_xticks(range(len(names)), names, rotation=20, fontsize=7)
    ax2.set_ylabel("blocks served per second")
    ax2.legend(fontsize=7)
    fig.suptitle(f"omnisonar service, {PARTICLES} particles per session")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
