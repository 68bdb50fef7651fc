"""Load on the localization service: a local uvicorn, clients streaming blocks over HTTP.

Each client owns a session at 2,000 particles on the paper scene (walls rasterized at 5 cm)
and streams blocks of a simulated run (``paper-a``, 0 dB per-sample noise, cycled); request
bodies are encoded once, so the client (on the same two cores) costs little.

(a) paced, for ``--minutes`` (default 2; the issue's 10 is ``--minutes 10``): 8 clients at
    real time (one block every 1.023 s) and 2 at 10x real time (one every 102.3 ms) at once,
    every client moving to the next of 40 maps every 20 blocks (a new session there): p50,
    p95, p99 latency per group, errors, and the server's RSS and the machine's 1-minute load
    average every 2 s (other processes share the cores: the load says how much).
(b) saturation: 4 clients back to back, against the filter alone (heat map + filter step)
    in this process on 4 threads, interleaved round by round so both see the same machine
    load; once per checkpoint policy (after every block with fsync, the default; every 10
    blocks; off). Also one client back to back against one thread (latency per block).
(c) decompression bombs: map uploads whose ``G`` header declares 512 MiB and 2 GiB of
    float64 zeros (0.5 and 2 MB deflated) sent to a fresh server: status, and the server's
    peak RSS (``VmHWM``) before and after each.

Writes ``benchmarks/results/service_load.json`` and ``service_load.png``.
Run: ``PYTHONPATH=. .venv/bin/python -m benchmarks.service_load [--minutes M]``.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import statistics
import tempfile
import threading
import time
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import httpx
import matplotlib
import matplotlib.ticker
import numpy as np
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
from service.sessions import BlockInput, FilterSpec

matplotlib.use("Agg")

OUT = Path(__file__).parent / "results"
PARTICLES = 2000
RUN_BLOCKS = 16
N_MAPS = 40
BLOCKS_PER_MAP = 20
#: name -> server environment of each checkpoint policy measured in (b)
POLICIES = {
    "every block + fsync (default)": {},
    "every 10 blocks": {"OMNISONAR_CHECKPOINT_EVERY_BLOCKS": "10"},
    "off": {"OMNISONAR_CHECKPOINT": "false"},
}


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


class Blocks:
    """The run's blocks, encoded once: raw bodies, query parameters, float64 samples."""

    def __init__(self, run: Run) -> None:
        self.run = run
        self.bodies = [run.samples[k].astype("<f4").tobytes() for k in range(run.n_blocks)]
        self.samples = [run.samples[k].astype(np.float64) for k in range(run.n_blocks)]
        self.pose = {k: float(v) for k, v in zip("x y yaw".split(), run.pose[0], strict=True)}

    def params(self, seq: int) -> dict[str, Any]:
        k = seq % self.run.n_blocks
        return {"seq": seq, "fs_hz": self.run.config.fs_hz,
                "speed_m_s": float(self.run.speed_m_s[k]),
                "yaw_rate_rad_s": float(self.run.yaw_rate_rad_s[k])}

    def input(self, seq: int) -> BlockInput:
        k = seq % self.run.n_blocks
        return BlockInput(seq=seq, samples=self.samples[k],
                          speed_m_s=float(self.run.speed_m_s[k]),
                          yaw_rate_rad_s=float(self.run.yaw_rate_rad_s[k]),
                          dt_s=0.0 if seq == 0 else self.run.config.block_s)


# ---- HTTP clients -------------------------------------------------------------------------
def _open(http: httpx.Client, blocks: Blocks, map_id: str) -> str:
    r = http.post("/sessions", json={"map_id": map_id, "particles": PARTICLES,
                                     "initial_pose": blocks.pose})
    r.raise_for_status()
    return str(r.json()["id"])


def _post(http: httpx.Client, sid: str, blocks: Blocks, seq: int) -> bool:
    r = http.post(f"/sessions/{sid}/blocks", params=blocks.params(seq),
                  content=blocks.bodies[seq % len(blocks.bodies)],
                  headers={"content-type": "application/octet-stream"})
    return r.status_code == 200


def paced_client(url: str, blocks: Blocks, period_s: float, until: float, first_map: int,
                 out: dict[str, Any]) -> None:
    """Blocks every ``period_s`` until ``until``; a new session on the next map every
    :data:`BLOCKS_PER_MAP` blocks (the old one deleted)."""
    lat: list[float] = []
    errors, n, m = 0, 0, first_map
    with httpx.Client(base_url=url, timeout=60) as http:
        sid = _open(http, blocks, f"paper-{m % N_MAPS:02d}")
        t_next = time.perf_counter()
        while time.perf_counter() < until:
            time.sleep(max(0.0, t_next - time.perf_counter()))
            t_next += period_s
            if n and n % BLOCKS_PER_MAP == 0:
                http.delete(f"/sessions/{sid}")
                m += 1
                sid = _open(http, blocks, f"paper-{m % N_MAPS:02d}")
            t0 = time.perf_counter()
            errors += not _post(http, sid, blocks, n % BLOCKS_PER_MAP)
            lat.append(1e3 * (time.perf_counter() - t0))
            n += 1
        http.delete(f"/sessions/{sid}")
    out["latency_ms"], out["errors"] = lat, errors


def back_to_back(url: str, blocks: Blocks, n_clients: int, n_blocks: int) -> dict[str, Any]:
    """``n_clients`` sessions, ``n_blocks`` each as fast as answered: blocks/s, latencies."""
    outs: list[list[float]] = [[] for _ in range(n_clients)]
    errs = [0] * n_clients
    ready = threading.Barrier(n_clients + 1)

    def client(i: int) -> None:
        with httpx.Client(base_url=url, timeout=60) as http:
            sid = _open(http, blocks, "paper-00")
            _post(http, sid, blocks, 0)  # the session's first block: not timed
            ready.wait()
            for seq in range(1, n_blocks + 1):
                t0 = time.perf_counter()
                errs[i] += not _post(http, sid, blocks, seq)
                outs[i].append(1e3 * (time.perf_counter() - t0))
            http.delete(f"/sessions/{sid}")

    threads = [threading.Thread(target=client, args=(i,)) for i in range(n_clients)]
    for t in threads:
        t.start()
    ready.wait()
    t0 = time.perf_counter()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    lat = np.concatenate(outs)
    return {"blocks_per_s": lat.size / wall, "p50_ms": float(np.median(lat)),
            "errors": int(sum(errs))}


# ---- the filter alone, in this process ----------------------------------------------------
def filter_alone(factory: LocalizationFactory, blocks: Blocks, n_threads: int,
                 n_blocks: int) -> dict[str, Any]:
    """``n_threads`` trackers updated back to back in threads: blocks/s, median ms."""
    spec = FilterSpec(particles=PARTICLES, seed=0,
                      initial_pose=(blocks.pose["x"], blocks.pose["y"], blocks.pose["yaw"]))
    trackers = [factory.create("paper-00", spec) for _ in range(n_threads)]
    for tr in trackers:
        tr.update(blocks.input(0))
    times: list[list[float]] = [[] for _ in range(n_threads)]
    ready = threading.Barrier(n_threads + 1)

    def work(i: int) -> None:
        ready.wait()
        for seq in range(1, n_blocks + 1):
            t0 = time.perf_counter()
            trackers[i].update(blocks.input(seq))
            times[i].append(1e3 * (time.perf_counter() - t0))

    threads = [threading.Thread(target=work, args=(i,)) for i in range(n_threads)]
    for t in threads:
        t.start()
    ready.wait()
    t0 = time.perf_counter()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    return {"blocks_per_s": n_threads * n_blocks / wall,
            "p50_ms": float(np.median(np.concatenate(times)))}


# ---- the phases ---------------------------------------------------------------------------
def paced(maps_dir: Path, tmp: Path, blocks: Blocks, minutes: float) -> dict[str, Any]:
    """(a): 8 clients at 1x and 2 at 10x for ``minutes``, RSS sampled every 2 s."""
    env = {"OMNISONAR_DEFAULT_MAP": "false", "OMNISONAR_SESSIONS_DIR": str(tmp / "sessions"),
           "OMNISONAR_MAX_SESSIONS_PER_KEY": "32"}
    block_s = blocks.run.config.block_s
    with ServerProcess(maps_dir, env=env) as srv:
        back_to_back(srv.url, blocks, 1, 3)  # warm-up: numba cache, FFT plans
        rss: list[tuple[float, float]] = []
        loadavg: list[tuple[float, float]] = []
        sessions: list[tuple[float, int]] = []
        t0 = time.perf_counter()
        until = t0 + 60 * minutes
        groups = {"8 clients at real time": (8, block_s), "2 clients at 10x": (2, block_s / 10)}
        outs: dict[str, list[dict[str, Any]]] = {g: [{} for _ in range(n)]
                                                 for g, (n, _) in groups.items()}
        threads = [threading.Thread(target=paced_client,
                                    args=(srv.url, blocks, period, until, 5 * i + 3 * j, o))
                   for j, (g, (_, period)) in enumerate(groups.items())
                   for i, o in enumerate(outs[g])]
        for t in threads:
            t.start()
        while any(t.is_alive() for t in threads):
            now = time.perf_counter() - t0
            rss.append((now, rss_bytes(srv.pid) / 2**20))
            loadavg.append((now, os.getloadavg()[0]))
            health = httpx.get(f"{srv.url}/health", timeout=10).json()
            sessions.append((now, int(health["sessions"])))
            time.sleep(2.0)
        for t in threads:
            t.join()
    out: dict[str, Any] = {"minutes": minutes, "maps": N_MAPS, "rss_mb": rss,
                           "load_average_1min": loadavg, "sessions_open": sessions,
                           "groups": {}}
    for g, group in outs.items():
        lat = np.concatenate([o["latency_ms"] for o in group])
        out["groups"][g] = {
            "blocks": int(lat.size), "errors": int(sum(o["errors"] for o in group)),
            **{f"p{q}_ms": float(np.percentile(lat, q)) for q in (50, 95, 99)},
            "latency_ms": lat.tolist()}
    return out


def saturation(maps_dir: Path, tmp: Path, blocks: Blocks, rounds: int,
               n_blocks: int) -> dict[str, Any]:
    """(b): HTTP vs the filter alone, interleaved, per checkpoint policy."""
    factory = LocalizationFactory(MapStore(maps_dir))
    out: dict[str, Any] = {}
    for name, extra in POLICIES.items():
        env = {"OMNISONAR_DEFAULT_MAP": "false",
               "OMNISONAR_SESSIONS_DIR": str(tmp / f"sessions-{len(out)}"), **extra}
        with ServerProcess(maps_dir, env=env) as srv:
            back_to_back(srv.url, blocks, 1, 3)
            rows = []
            for _ in range(rounds):
                alone1 = filter_alone(factory, blocks, 1, n_blocks)
                http1 = back_to_back(srv.url, blocks, 1, n_blocks)
                alone4 = filter_alone(factory, blocks, 4, n_blocks)
                http4 = back_to_back(srv.url, blocks, 4, n_blocks)
                rows.append({"alone_1": alone1, "http_1": http1, "alone_4": alone4,
                             "http_4": http4})
        med = {k: statistics.median(r[k]["blocks_per_s"] for r in rows) for k in rows[0]}
        out[name] = {
            "rounds": rows, "median_blocks_per_s": med,
            "ratio_4": statistics.median(r["alone_4"]["blocks_per_s"]
                                         / r["http_4"]["blocks_per_s"] for r in rows),
            "ratio_1": statistics.median(r["http_1"]["p50_ms"] / r["alone_1"]["p50_ms"]
                                         for r in rows),
            "errors": sum(r[k]["errors"] for r in rows for k in ("http_1", "http_4")),
        }
        print(f"{name:32s} filter alone {med['alone_4']:6.1f} blocks/s, HTTP "
              f"{med['http_4']:6.1f} (4 clients): ratio {out[name]['ratio_4']:.2f}; "
              f"1 client p50 ratio {out[name]['ratio_1']:.2f}", flush=True)
    return out


def bomb_bytes(cells: int) -> bytes:
    """A map file (the paper raster's other keys, valid) whose ``G`` declares ``cells``
    float64 zeros, deflated; written by streaming, never holding the array."""
    valid = io.BytesIO()
    with tempfile.TemporaryDirectory() as d:
        valid.write(write_map(Path(d) / "m.npz", raster_map("paper")).read_bytes())
    buf = io.BytesIO()
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": (cells // 1024, 1024)})
    with zipfile.ZipFile(valid) as src, zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in src.namelist():
            if name != "G.npy":
                zf.writestr(name, src.read(name))
        with zf.open("G.npy", "w", force_zip64=True) as fh:
            fh.write(header.getvalue())
            zero = bytes(1 << 20)
            for _ in range(cells * 8 // len(zero)):
                fh.write(zero)
    return buf.getvalue()


def _hwm_bytes(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise ValueError(f"no VmHWM for pid {pid}")


def bombs(maps_dir: Path, tmp: Path) -> list[dict[str, Any]]:
    """(c): each bomb against a fresh server; peak RSS before and after the upload."""
    env = {"OMNISONAR_DEFAULT_MAP": "false", "OMNISONAR_SESSIONS_DIR": str(tmp / "s-bomb")}
    rows = []
    for cells in (64 << 20, 256 << 20):
        data = bomb_bytes(cells)
        with ServerProcess(maps_dir, env=env) as srv:
            before = _hwm_bytes(srv.pid)
            r = httpx.post(f"{srv.url}/maps", params={"map_id": "bomb"}, content=data,
                           headers={"content-type": "application/octet-stream"}, timeout=120)
            rows.append({"declared_mib": cells * 8 / 2**20, "upload_mb": len(data) / 1e6,
                         "status": r.status_code, "field": r.json().get("field"),
                         "peak_rss_before_mib": before / 2**20,
                         "peak_rss_after_mib": _hwm_bytes(srv.pid) / 2**20,
                         "rss_after_mib": rss_bytes(srv.pid) / 2**20,
                         "stored": (maps_dir / "bomb.npz").exists()})
        print(f"bomb declaring {rows[-1]['declared_mib']:.0f} MiB in "
              f"{rows[-1]['upload_mb']:.2f} MB: {r.status_code}, peak RSS "
              f"{rows[-1]['peak_rss_before_mib']:.0f} -> {rows[-1]['peak_rss_after_mib']:.0f} MiB",
              flush=True)
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.service_load",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=2.0,
                    help="length of the paced run (a); the issue's figure is 10")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds of (b)")
    ap.add_argument("--blocks", type=int, default=30, help="blocks per client per round")
    args = ap.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        for i in range(N_MAPS):
            write_map(tmp / "maps" / f"paper-{i:02d}.npz", raster_map("paper"))
        blocks = Blocks(simulate_default_run("paper-a", seed=7, n_blocks=RUN_BLOCKS))
        bomb = bombs(tmp / "maps", tmp)
        sat = saturation(tmp / "maps", tmp, blocks, args.rounds, args.blocks)
        load = paced(tmp / "maps", tmp, blocks, args.minutes)
    for g, c in load["groups"].items():
        print(f"{g:24s} {c['blocks']} blocks, errors {c['errors']}, p50 {c['p50_ms']:.1f} ms, "
              f"p95 {c['p95_ms']:.1f} ms, p99 {c['p99_ms']:.1f} ms")
    rss = [m for _, m in load["rss_mb"]]
    print(f"RSS over {args.minutes:g} min with {N_MAPS} maps: {rss[0]:.0f} -> max "
          f"{max(rss):.0f} -> last {rss[-1]:.0f} MB")
    la = [v for _, v in load["load_average_1min"]]
    print(f"load average (1 min) before {load_before[0]:.2f}; during (a) median "
          f"{statistics.median(la):.2f}, max {max(la):.2f}")
    summary = {
        "particles": PARTICLES, "cores": os.cpu_count(),
        "load_average_before": {"1min": load_before[0], "5min": load_before[1],
                                "15min": load_before[2]},
        "load_average_paced": {"median": statistics.median(la), "min": min(la),
                               "max": max(la)},
        "load_average_end_1min": os.getloadavg()[0],
        "args": vars(args),
        "bombs": bomb,
        "saturation": {k: {kk: vv for kk, vv in v.items() if kk != "rounds"}
                       for k, v in sat.items()},
        "saturation_rounds": {k: v["rounds"] for k, v in sat.items()},
        "paced": {**{k: v for k, v in load.items() if k != "groups"},
                  "groups": {g: {k: v for k, v in c.items() if k != "latency_ms"}
                             for g, c in load["groups"].items()}},
    }
    (OUT / "service_load.json").write_text(json.dumps(summary, indent=1))
    plot(sat, load, OUT / "service_load.png")
    return 0


def plot(sat: dict[str, Any], load: dict[str, Any], path: Path) -> None:
    fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(15, 4.2))
    for g, c in load["groups"].items():
        lat = np.sort(c["latency_ms"])
        ax1.plot(lat, np.arange(1, lat.size + 1) / lat.size,
                 label=f"{g}: p50 {c['p50_ms']:.0f}, p99 {c['p99_ms']:.0f} ms")
    ax1.set_xscale("log")
    ax1.xaxis.set_major_locator(matplotlib.ticker.FixedLocator([10, 20, 50, 100, 200, 500,
                                                                1000, 2000]))
    ax1.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax1.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax1.set_xlabel("latency per block (ms)")
    ax1.set_ylabel("CDF")
    ax1.set_title(f"(a) paced, {load['minutes']:g} min, sessions over {N_MAPS} maps",
                  fontsize=9)
    ax1.legend(fontsize=7, loc="lower right")
    names = list(sat)
    x = np.arange(len(names))
    alone = [sat[n]["median_blocks_per_s"]["alone_4"] for n in names]
    http = [sat[n]["median_blocks_per_s"]["http_4"] for n in names]
    ax2.bar(x - 0.2, alone, 0.4, label="filter alone, 4 threads, same process")
    ax2.bar(x + 0.2, http, 0.4, label="HTTP, 4 clients back to back")
    for i, n in enumerate(names):
        ax2.text(x[i] + 0.2, http[i], f"{sat[n]['ratio_4']:.2f}x", ha="center",
                 va="bottom", fontsize=8)
    ax2.set_xticks(x, [n.replace(" (default)", "\n(default)") for n in names], fontsize=7)
    ax2.set_ylabel("blocks per second")
    ax2.set_ylim(0, 1.35 * max(alone + http))
    ax2.set_title("(b) saturation by checkpoint policy (median of rounds)", fontsize=9)
    ax2.legend(fontsize=7, loc="upper center", ncol=1, framealpha=0.9)
    t, mb = zip(*load["rss_mb"], strict=True)
    ax3.plot(np.asarray(t) / 60, mb, lw=1.0)
    ax3.set_xlabel("minutes")
    ax3.set_ylabel("server RSS (MiB)")
    ax3.set_ylim(0, max(mb) * 1.15)
    ax3.set_title("(a) server RSS, and the machine's load", fontsize=9)
    lt, la = zip(*load["load_average_1min"], strict=True)
    ax3b = ax3.twinx()
    ax3b.plot(np.asarray(lt) / 60, la, color="tab:gray", lw=0.8, ls="--")
    ax3b.set_ylabel(f"1-min load average ({os.cpu_count()} cores), dashed", color="tab:gray")
    ax3b.set_ylim(0, max(la) * 1.15)
    fig.suptitle(f"omnisonar service, {PARTICLES} particles per session, "
                 f"{os.cpu_count()} cores shared by server, clients and other processes "
                 f"(1-min load average during (a): median "
                 f"{np.median(la):.1f}, max {max(la):.1f})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    raise SystemExit(main())
