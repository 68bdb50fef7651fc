"""Benchmark of the FDTD engine (issue 4): cell updates per second of the numba kernels
(the temporally blocked default, ``FdtdSolver(backend="numba")``, and the previous
one-step-per-sweep kernel, ``backend="numba-step"``) and the numpy twin, float32/float64, 1
and 2 threads, on 500^2 and 1000^2 grids with a 24-cell PML; the memory-bandwidth ceiling
(copy and triad over grid-sized arrays) measured in the same process; the denormal guard
on/off; on the fitted paper-scene domain (walls + free field, PML) the two numba kernels
interleaved, >= 5 repeats each, median and spread, with the load average before and after,
and the seconds per simulated 1.023 s block (extrapolated from the per-step time).

A "cell update" is p, qx and qy of one cell of one field for one step. The engine advances
two fields (with and without walls), so one grid step is two cell updates; both counts are
reported. Bytes model: one step moves p, qx, qy in and out once (24 B per float32 field-cell
update); the blocked kernel streams them from memory once per sweep of ``steps_per_sweep``
steps (24 / steps_per_sweep B per update at the memory level, the rest from the core's L2).

Writes benchmarks/results/fdtd.json and fdtd.png (and engines.png, fdtd_vs_ism.png). Runs in
about three minutes; waits (up to 10 min) for a 1-minute load average below 0.7 before the
paper-domain measurement, which runs first. ``--only paper`` reruns just that measurement
and updates its key in an existing fdtd.json; ``--only engines`` likewise reruns the
engine comparison (engines.png, fdtd_vs_ism.png; seconds). The engines chart's second panel,
which built-in scenes need edge diffraction, is read from ism_diffraction.json (written by
``benchmarks/ism_diffraction.py``) and copied into fdtd.json. On a shared machine run the
comparison with ``NUMBA_NUM_THREADS=1``: its CPU seconds then count no spin-waiting thread (the
image-source render is parallel; the FDTD grids here step on one thread anyway).
"""

from __future__ import annotations

import json
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any

# a script run from benchmarks/ must not shadow the packages: import from the repository root
import matplotlib
import matplotlib.pyplot as plt
import numba
import numpy as np
from numba import njit, prange

from mapping.path import builtin_path
from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from mapping.simulate.fdtd import (
    STEPS_PER_SWEEP,
    FdtdConfig,
    FdtdGrid,
    FdtdSolver,
    new_state,
    setup_for_scene,
)
from tests.mapping.simulate.fdtd.naive import NumpyFdtdSolver

_HERE = Path(__file__).resolve().parent
matplotlib.use("Agg")

OUT = Path(__file__).resolve().parent / "results"
C = 340.0


@njit(parallel=True, cache=True)
def _triad(a: np.ndarray, b: np.ndarray, c: np.ndarray, s: float) -> None:  # pragma: no cover
    for i in prange(a.size):
        a[i] = b[i] + s * c[i]


@njit(parallel=True, cache=True)
def _copy(a: np.ndarray, b: np.ndarray) -> None:  # pragma: no cover
    for i in prange(a.size):
        a[i] = b[i]


def _best(fn: Any, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)) if repeats > 2 else float(min(times))


def bandwidth(n_cells: int, dtype: str, threads: int) -> dict[str, float]:
    """Copy and triad GB/s over arrays of ``n_cells`` elements (numba, ``threads``)."""
    numba.set_num_threads(threads)
    a, b, c = (np.ones(n_cells, dtype=dtype) for _ in range(3))
    _triad(a, b, c, 0.5)
    _copy(a, b)
    # warm-up: right after a switch from 1 to 2 threads the second CPU of this (virtual)
    # machine needs a while before parallel regions run at full speed; without this the first
    # 2-thread rows measured 10-50x too slow
    t_end = time.perf_counter() + 1.0
    while time.perf_counter() < t_end:
        _triad(a, b, c, 0.5)
    reps = 20
    t_triad = _best(lambda: [_triad(a, b, c, 0.5) for _ in range(reps)], 3) / reps
    t_copy = _best(lambda: [_copy(a, b) for _ in range(reps)], 3) / reps
    nb = a.nbytes
    return {"copy_GB_s": 2 * nb / t_copy / 1e9, "triad_GB_s": 3 * nb / t_triad / 1e9}


def _solver(n: int, dtype: str, backend: str, n_fields: int, guard: bool = True) -> FdtdSolver:
    cfg = FdtdConfig(pml_cells=24, dtype=dtype, denormal_guard=guard)
    grid = FdtdGrid(origin_m=(0.0, 0.0), shape=(n, n), grid_step_m=0.005, pml_cells=24)
    if backend == "numpy":  # the plain numpy twin (tests/mapping/simulate/fdtd/naive.py)
        return NumpyFdtdSolver(grid, cfg, C, None, n_fields)
    return FdtdSolver(grid, cfg, C, None, n_fields, backend)


def _kick(s: FdtdSolver, n_steps: int) -> None:
    centre = np.array(s.grid.origin_m) + s.grid.shape[0] // 2 * s.grid.grid_step_m
    g = np.zeros(n_steps)
    g[: min(10, n_steps)] = 1.0
    s.run_static(centre, centre + 0.05, g)


def kernel_rate(n: int, dtype: str, backend: str, threads: int, n_fields: int,
                steps: int) -> float:
    """Grid cells x steps per second (one field-cell update per field)."""
    numba.set_num_threads(threads)
    s = _solver(n, dtype, backend, n_fields)
    _kick(s, 2)
    t = _best(lambda: _kick(s, steps), 3)
    return n * n * steps / t


def kernel_rates(n: int, dtype: str, backends: tuple[str, ...], threads: int, n_fields: int,
                 steps: int, repeats: int = 5) -> dict[str, float]:
    """:func:`kernel_rate` of several backends timed interleaved (median of ``repeats``):
    a burst of load from other jobs hits all of them alike."""
    numba.set_num_threads(threads)
    solvers = {b: _solver(n, dtype, b, n_fields) for b in backends}
    for s in solvers.values():
        _kick(s, 2)
    times: dict[str, list[float]] = {b: [] for b in backends}
    for _ in range(repeats):
        for b, s in solvers.items():
            t = time.perf_counter()
            _kick(s, steps)
            times[b].append(time.perf_counter() - t)
    return {b: n * n * steps / float(np.median(ts)) for b, ts in times.items()}


def _wait_quiet(max_load: float, timeout_s: float) -> dict[str, Any]:
    """Wait until the 1-minute load average is below ``max_load`` (or the timeout)."""
    t0 = time.perf_counter()
    while os.getloadavg()[0] >= max_load and time.perf_counter() - t0 < timeout_s:
        time.sleep(10)
    return {"waited_s": time.perf_counter() - t0, "max_load": max_load,
            "quiet": os.getloadavg()[0] < max_load}


def _spin(fn: Any, seconds: float) -> None:
    t_end = time.perf_counter() + seconds
    while time.perf_counter() < t_end:
        fn()


def denormal_effect(n: int, steps: int) -> dict[str, float]:
    """Rate with and without the denormal guard after a pulse has spread (float32, 1 thread)."""
    numba.set_num_threads(1)
    out = {}
    solvers = {}
    for guard in (True, False):
        s = _solver(n, "float32", "numba", 1, guard)
        _kick(s, 400)
        tiny = np.abs(s.p[0] - s.offset)
        out[f"subnormal_fraction_guard_{guard}"] = float(
            np.mean((tiny > 0) & (tiny < np.finfo(np.float32).tiny)))
        solvers[guard] = s
    # interleaved repeats, median: a burst of load from other jobs hits both variants alike
    times: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(7):
        for guard, s in solvers.items():
            t0 = time.perf_counter()
            _kick(s, steps)
            times[guard].append(time.perf_counter() - t0)
    for guard, ts in times.items():
        out[f"Mcell_s_guard_{guard}"] = n * n * steps / float(np.median(ts)) / 1e6
    out["slowdown_without_guard"] = out["Mcell_s_guard_True"] / out["Mcell_s_guard_False"]
    return out


def paper_block(threads: int, steps: int = 4 * STEPS_PER_SWEEP,
                repeats: int = 7) -> dict[str, Any]:
    """The fitted paper-scene domain (scene ``paper``, path ``paper-a``, Table 2 grid, two
    fields, walls, 24-cell PML): the blocked kernel and the one-step kernel interleaved,
    ``repeats`` timings of ``steps`` steps each (moving sonar, real source signal); medians,
    spread, ratio, seconds per simulated 1.023 s block."""
    numba.set_num_threads(threads)
    sonar = SonarConfig()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        setup = setup_for_scene(builtin_scene("paper"), builtin_path("paper-a"), sonar,
                                FdtdConfig(), n_blocks=1)
    from mapping.simulate.fdtd import advance

    states = {b: new_state(setup, b) for b in ("numba", "numba-step")}
    for st in states.values():
        advance(setup, st, STEPS_PER_SWEEP)  # compile
    # the second CPU of this VM needs a moment at full speed after a thread-count switch
    def both() -> None:
        for st in states.values():
            advance(setup, st, STEPS_PER_SWEEP)

    _spin(both, 1.0)
    load_before = os.getloadavg()
    times: dict[str, list[float]] = {b: [] for b in states}
    shares: dict[str, list[float]] = {b: [] for b in states}
    for _ in range(repeats):
        for b, st in states.items():
            t, c = time.perf_counter(), time.process_time()
            advance(setup, st, steps)
            times[b].append(time.perf_counter() - t)
            shares[b].append((time.process_time() - c) / (times[b][-1] * threads))
    load_after = os.getloadavg()
    nx, ny = setup.grid.shape
    steps_per_block = sonar.block_s / setup.fdtd.time_step_s
    out: dict[str, Any] = {"grid": [nx, ny], "threads": threads, "steps_timed": steps,
                           "repeats": repeats, "steps_per_block": steps_per_block,
                           "load_average_before": load_before,
                           "load_average_after": load_after}
    for b, ts in times.items():
        per_step = np.array(ts) / steps
        rate = 2 * nx * ny / per_step / 1e6
        q25, q75 = np.percentile(rate, [25, 75])
        out[b] = {"seconds_per_step": float(np.median(per_step)),
                  "seconds_per_block": float(np.median(per_step)) * steps_per_block,
                  "seconds_per_block_range": [float(per_step.min() * steps_per_block),
                                              float(per_step.max() * steps_per_block)],
                  "field_Mcell_s": float(np.median(rate)),
                  "field_Mcell_s_min": float(rate.min()),
                  "field_Mcell_s_max": float(rate.max()),
                  "field_Mcell_s_iqr": [float(q25), float(q75)],
                  "field_Mcell_s_all": [float(r) for r in rate],
                  # CPU seconds of this process / (wall seconds x threads): well below 1
                  # when other jobs took the cores (OpenMP spin-waits count as CPU, so a
                  # value near 1 does not prove the threads had the cores)
                  "cpu_share_all": [float(x) for x in shares[b]],
                  "grid_Mcell_s": float(np.median(rate)) / 2}
    out["numba"]["steps_per_sweep"] = STEPS_PER_SWEEP
    out["speedup_vs_one_step_kernel"] = (out["numba-step"]["seconds_per_step"]
                                         / out["numba"]["seconds_per_step"])
    out["field_Mcell_s"] = out["numba"]["field_Mcell_s"]
    out["seconds_per_block"] = out["numba"]["seconds_per_block"]
    return out


def _one_wall() -> tuple[Any, Any, SonarConfig, float]:
    from mapping.path import polyline_path
    from mapping.scene import Scene, Wall

    sonar = SonarConfig(sequence_length=31, carrier_hz=2500.0, chip_rate_hz=2500.0,
                        fs_hz=10_000.0, repetitions=4)
    scene = Scene(name="one-wall", walls=[Wall(start=(-0.3, 0.8), end=(1.3, 0.8))])
    v = 4.0
    traj = polyline_path([[0.0, 0.0], [0.8, 0.4]], speed_m_s=v, name="oblique")
    return scene, traj, sonar, v


def _dispersed(x: np.ndarray, path_m: float, fs_hz: float, dx: float, dt: float) -> np.ndarray:
    from mapping.simulate.fdtd import numerical_wavenumber

    f = np.fft.rfftfreq(x.size, 1 / fs_hz)
    k = 2 * np.pi * f / C
    kn = np.array([numerical_wavenumber(fi, np.pi / 2, dx, dt, C) if 0 < fi < C / (4 * dx)
                   else ki for fi, ki in zip(f, k, strict=True)])
    return np.fft.irfft(np.fft.rfft(x) * np.exp(-1j * (kn - k) * path_m), x.size)


def compare_engines(grid_steps_m: tuple[float, ...] = (0.02, 0.014, 0.01)) -> dict[str, Any]:
    """Cost per block against heat-map peak error, image-source vs FDTD, one-wall scene
    (scaled-down signal: 2.5 kHz carrier, L = 31, M = 4; sonar at 4 m/s).

    The truth is the geometry: the specular echo's range at the block midpoint (from the
    image-source path table) and its angle to the velocity.
    """
    from mapping.heatmap import doppler_heatmap, find_peak
    from mapping.simulate import iter_blocks
    from mapping.simulate.fdtd import simulate_fdtd
    from mapping.simulate.ism import IsmConfig

    scene, traj, sonar, v = _one_wall()
    def ism_block() -> Any:
        return next(iter(iter_blocks(scene, traj, sonar, 1, IsmConfig(spreading="2d"),
                                     np.random.default_rng(0))))

    ism_block()  # compile / warm caches
    t = time.process_time()  # CPU seconds of all threads: robust on a shared machine
    block = ism_block()
    ism_s = time.process_time() - t
    first = int(np.argmin(block.paths.order))
    true_range = C * float(block.paths.delay_s[first]) / 2
    true_angle = float(block.paths.angle_to_velocity_rad[first])
    y_mid = traj.position(np.array([sonar.block_s / 2]))[0, 1]

    def errors(x: np.ndarray) -> tuple[dict[str, float], Any]:
        hm = doppler_heatmap(x, v, sonar)
        pk = find_peak(hm)
        return {"range_error_m": abs(pk.range_m - true_range),
                "angle_error_deg": abs(np.degrees(pk.angle_rad - true_angle)),
                "n_tau": pk.n_tau, "n_theta": pk.n_theta}, hm

    ism_err, ism_hm = errors(block.samples)
    out: dict[str, Any] = {"true_range_m": true_range, "true_angle_deg": np.degrees(true_angle),
                           "numba_threads": numba.get_num_threads(),
                           "ism": {"cpu_seconds_per_block": ism_s, **ism_err,
                                   "block_s": sonar.block_s}, "fdtd": []}
    maps = {}
    for dx in grid_steps_m:
        dt = 0.567 * dx / C
        cfg = FdtdConfig(grid_step_m=dx, time_step_s=dt, pml_cells=20, margin_m=0.2,
                         warmup_s=0.008)
        t = time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            x = simulate_fdtd(scene, traj, sonar, cfg, n_blocks=1).samples[0].astype(float)
        cost = time.process_time() - t
        ref = _dispersed(block.samples, 2 * (0.8 - y_mid), sonar.fs_hz, dx, dt)
        corr = float(np.dot(x, ref) / (np.linalg.norm(x) * np.linalg.norm(ref)))
        corr_raw = float(np.dot(x, block.samples)
                         / (np.linalg.norm(x) * np.linalg.norm(block.samples)))
        err, hm = errors(x)
        err_ref, hm_ref = errors(ref)
        maps[dx] = (hm, hm_ref)
        out["fdtd"].append({"grid_step_m": dx, "cpu_seconds_per_block": cost, **err,
                            "corr_with_ism_dispersed": corr, "corr_with_ism_raw": corr_raw,
                            "ism_dispersed_n_tau": err_ref["n_tau"],
                            "ism_dispersed_n_theta": err_ref["n_theta"]})
        print(out["fdtd"][-1])
    out["diffraction_by_scene"] = _diffraction_by_scene()
    _plot_engines(out, maps, ism_hm)
    return out


def _diffraction_by_scene() -> dict[str, Any]:
    """Per built-in scene, diffracted vs specular energy and the cost of diffraction, as
    measured by ``benchmarks/ism_diffraction.py`` (not recomputed here)."""
    src = OUT / "ism_diffraction.json"
    keys = ("scene", "path", "diffracted_db_d1", "diffracted_db_d2", "ms_per_block_d0",
            "ms_per_block_d1", "ms_per_block_d2", "cost_ratio_d2")
    rows = json.loads(src.read_text())["scenes"]
    return {"source": str(src.relative_to(_HERE.parent)),
            "rows": [{k: r[k] for k in keys} for r in rows]}


def _diffraction_panel(ax: Any, diffraction: dict[str, Any]) -> None:
    """Horizontal bars: diffracted / specular energy (dB) per built-in scene, cost in the label."""
    floor_db = -45.0
    rows = sorted(diffraction["rows"], key=lambda r: -(r["diffracted_db_d2"] or -np.inf))
    labels = [f"{r['scene']}\ncost x{r['cost_ratio_d2']:.1f} "
              f"({r['ms_per_block_d0']:.0f} -> {r['ms_per_block_d2']:.0f} ms/block)" for r in rows]
    for i, r in enumerate(rows):
        d2, d1 = r["diffracted_db_d2"], r["diffracted_db_d1"]
        if d2 is None:
            ax.text(floor_db + 1, i, "none heard (closed room)", va="center", fontsize=7)
            continue
        ax.barh(i, d2 - floor_db, left=floor_db, color="tab:purple", height=0.55,
                label="diffraction order 2" if i == 0 else None)
        ax.plot([d1], [i], "|", color="k", ms=14, mew=2, label="order 1" if i == 0 else None)
        ax.text(d2 + 0.8, i, f"{d2:.0f} dB", va="center", fontsize=7)
    ax.set_yticks(range(len(rows)), labels, fontsize=7)
    ax.set_ylim(len(rows) - 0.5, -0.5)
    ax.set_xlim(floor_db, 0)
    ax.set_xlabel("diffracted / specular energy (dB; order 3, 3d, 3 blocks)", fontsize=8)
    ax.set_title("Which built-in scenes need edge diffraction (image source)", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")


def _plot_engines(res: dict[str, Any], maps: dict[float, Any], ism_hm: Any) -> None:
    fig, (ax, ax_d) = plt.subplots(1, 2, figsize=(12, 4.2),
                                   gridspec_kw={"width_ratios": [1.1, 1]})
    _diffraction_panel(ax_d, res["diffraction_by_scene"])
    ism = res["ism"]
    ax.scatter([ism["cpu_seconds_per_block"]], [ism["range_error_m"] * 1e3], color="tab:green",
               s=60, label="image source (2d)")
    fd = res["fdtd"]
    ax.plot([r["cpu_seconds_per_block"] for r in fd], [r["range_error_m"] * 1e3 for r in fd],
            "o-", color="tab:blue", label="FDTD (raw, dispersion not removed)")
    for i, r in enumerate(fd):  # labels left of the points, the last one below its point
        ax.annotate(f"dx {r['grid_step_m'] * 100:g} cm, corr {r['corr_with_ism_dispersed']:.3f}",
                    (r["cpu_seconds_per_block"], r["range_error_m"] * 1e3), fontsize=7,
                    xytext=(-8, -12 if i == len(fd) - 1 else 0), textcoords="offset points",
                    ha="right", va="center")
    ax.set_xscale("log")
    ax.set_xlabel(f"CPU seconds per simulated block ({ism['block_s']:.3f} s, one-wall scene)")
    ax.set_ylabel("heat-map peak range error (mm)")
    ax.set_title("Image source vs FDTD: cost vs agreement (one wall)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(OUT / "engines.png", dpi=120)
    dx = min(maps)
    hm, hm_ref = maps[dx]
    n = int(np.searchsorted(hm.ranges_m, 2.5))
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    ext = (0, hm.ranges_m[n - 1], 0, 180)
    a = hm.H[:, :n] / hm.H[:, :n].max()
    b = hm_ref.H[:, :n] / hm_ref.H[:, :n].max()
    for axi, img, title in ((axs[0], a, f"FDTD dx = {dx * 100:g} cm"),
                            (axs[1], b, "image source, grid dispersion applied"),
                            (axs[2], a - b, "FDTD - image source")):
        im = axi.imshow(img, aspect="auto", origin="lower", extent=ext,
                        cmap="RdBu_r" if img is not a and img is not b else "viridis")
        axi.set_title(title, fontsize=9)
        axi.set_xlabel("range (m)")
        fig.colorbar(im, ax=axi)
    axs[0].set_ylabel("angle to velocity (deg)")
    axs[2].text(0.02, 0.02, "residual: diffraction at the wall's free ends\n(ISM has none); "
                "peaks agree within one bin", transform=axs[2].transAxes, fontsize=7)
    fig.tight_layout()
    fig.savefig(OUT / "fdtd_vs_ism.png", dpi=120)


def _paper_rows() -> dict[str, Any]:
    quiet = _wait_quiet(0.7, 600.0)
    rows = [paper_block(th) for th in (1, 2)]
    print(quiet, rows)
    nx, ny = rows[0]["grid"]
    bw = bandwidth(nx * ny, "float32", 2)  # ceiling over arrays of the paper grid's size
    for r in rows:
        rate = r["field_Mcell_s"] * 1e6
        r["bytes_per_update_one_step"] = 24
        r["bytes_per_update_blocked_memory"] = 24 / STEPS_PER_SWEEP
        r["GB_s_moved_estimate_one_step_model"] = rate * 24 / 1e9
        r["GB_s_memory_estimate_blocked"] = rate * 24 / STEPS_PER_SWEEP / 1e9
        r["GB_s_moved_estimate_old_kernel"] = r["numba-step"]["field_Mcell_s"] * 1e6 * 24 / 1e9
        r.update(bw)
    return {"wait_for_quiet": quiet, "rows": rows}


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    res: dict[str, Any]
    if sys.argv[1:] == ["--only", "paper"]:
        res = json.loads((OUT / "fdtd.json").read_text())
        res["paper_block"] = _paper_rows()
        (OUT / "fdtd.json").write_text(json.dumps(res, indent=2))
        _plot(res)
        return
    if sys.argv[1:] == ["--only", "engines"]:
        res = json.loads((OUT / "fdtd.json").read_text())
        res["engines"] = compare_engines()
        res["engines"]["load_average"] = os.getloadavg()
        (OUT / "fdtd.json").write_text(json.dumps(res, indent=2))
        return
    t0 = time.perf_counter()
    res = {"load_average_start": os.getloadavg(), "cpus": os.cpu_count(),
           "numba": numba.__version__, "steps_per_sweep": STEPS_PER_SWEEP}
    res["paper_block"] = _paper_rows()  # first, on a quiet machine
    rows: list[dict[str, Any]] = []
    for n, steps in ((500, 4 * STEPS_PER_SWEEP), (1000, 2 * STEPS_PER_SWEEP)):
        for dtype in ("float32", "float64"):
            item = np.dtype(dtype).itemsize
            for threads in (1, 2):
                bw = bandwidth(n * n, dtype, threads)
                for nf in (1, 2):
                    backends = ("numba", "numba-step") if dtype == "float32" else ("numba",)
                    rates = kernel_rates(n, dtype, backends, threads, nf, steps)
                    for backend, rate in rates.items():
                        field_rate = rate * nf
                        moved = field_rate * 6 * item / 1e9  # p, qx, qy read + written
                        depth = STEPS_PER_SWEEP if backend == "numba" else 1
                        rows.append({"n": n, "dtype": dtype, "threads": threads,
                                     "fields": nf, "backend": backend,
                                     "grid_Mcell_s": rate / 1e6,
                                     "field_Mcell_s": field_rate / 1e6,
                                     "GB_s_moved_estimate": moved,
                                     "GB_s_memory_estimate": moved / depth, **bw,
                                     "fraction_of_triad": moved / bw["triad_GB_s"]})
                        print(rows[-1])
            rate = kernel_rate(n, dtype, "numpy", 1, 1, 2)
            rows.append({"n": n, "dtype": dtype, "threads": 1, "fields": 1, "backend": "numpy",
                         "grid_Mcell_s": rate / 1e6, "field_Mcell_s": rate / 1e6})
            print(rows[-1])
    res["kernels"] = rows
    for r in rows:
        if r["backend"] != "numpy" and r["fields"] == 1:
            base = next(x for x in rows if x["backend"] == "numpy" and x["n"] == r["n"]
                        and x["dtype"] == r["dtype"])
            r["speedup_vs_numpy"] = r["field_Mcell_s"] / base["field_Mcell_s"]
    res["denormals"] = denormal_effect(500, 2 * STEPS_PER_SWEEP)
    print(res["denormals"])
    res["engines"] = compare_engines()
    res["load_average_end"] = os.getloadavg()
    res["wall_s"] = time.perf_counter() - t0
    (OUT / "fdtd.json").write_text(json.dumps(res, indent=2))
    _plot(res)


def _plot(res: dict[str, Any]) -> None:
    rows: list[dict[str, Any]] = list(res["kernels"])
    fig, ax = plt.subplots(figsize=(11, 4.5))
    for p in res["paper_block"]["rows"]:
        for b in ("numba", "numba-step"):
            rows.append({"backend": b, "n": "paper", "dtype": "float32", "threads": p["threads"],
                         "fields": 2, "field_Mcell_s": p[b]["field_Mcell_s"],
                         "lo": p[b]["field_Mcell_s_min"], "hi": p[b]["field_Mcell_s_max"]})
    labels = [f"{r['backend']} {r['n']}{'' if r['n'] == 'paper' else '²'} {r['dtype'][5:]} "
              f"{r['threads']}t {r['fields']}f" for r in rows]
    palette = {"numba": "tab:blue", "numba-step": "tab:orange", "numpy": "tab:gray"}
    colors = [palette[r["backend"]] for r in rows]
    ax.bar(range(len(rows)), [r["field_Mcell_s"] for r in rows], color=colors)
    for i, r in enumerate(rows):
        if "lo" in r:  # paper domain: min-max over the repeats
            ax.plot([i, i], [r["lo"], r["hi"]], color="k", lw=1)
    ax.axhline(1500, color="tab:green", ls="--", lw=1)
    for i, r in enumerate(rows):
        if "triad_GB_s" in r:
            ceiling = r["triad_GB_s"] * 1e9 / (6 * (4 if r["dtype"] == "float32" else 8)) / 1e6
            ax.plot([i - 0.4, i + 0.4], [ceiling] * 2, color="tab:red", lw=1.5)
    ax.set_xticks(range(len(rows)), labels, rotation=75, fontsize=7)
    ax.set_ylabel("field-cell updates / s (M)")
    ax.set_yscale("log")
    la = res["paper_block"]["rows"][0]["load_average_before"]  # the headline rows' load
    ax.set_title(f"FDTD kernels (24-cell PML; blue: {STEPS_PER_SWEEP} steps per sweep, "
                 f"orange: one step per sweep); red: triad ceiling at 24/48 B per update "
                 f"(one-step model); green: 1.5 G goal; paper rows at load average {la[0]:.2f} "
                 f"on {res['cpus']} CPUs (bars: min-max of the repeats)", fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT / "fdtd.png", dpi=120)


if __name__ == "__main__":
    main()
