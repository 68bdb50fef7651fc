"""Benchmark: time per block of the Doppler heat map (paper eq. 1) against a plain reference.

Measured in one process on the same block (Table 1: B = 40,920 samples, 30 directions):

* shipped  - ``mapping.heatmap.doppler_heatmap`` defaults (spectral method, numba, 8 taps);
* reference - plain numpy/scipy: ``scipy.signal.resample`` of the block (with neighbour samples)
  for every ratio alpha, then fold, numpy FFT correlation and envelope;
* a sweep (one thread) of interpolator length for both methods (spectral, direct windowed
  sinc), with the error of each against the exact answer: eq. 1 applied to the echo evaluated
  from geometry at the stretched times (no interpolation at all).

Wall-clock medians and CPU-time medians are both recorded (the machine is shared; CPU time is
less sensitive to other load) along with the load average. Writes
``benchmarks/results/heatmap.json`` and ``heatmap.png``. Run: ``python -m benchmarks.heatmap``.
"""

from __future__ import annotations

import json
import math
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import matplotlib
import numba

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import scipy.fft
import scipy.signal

from mapping.heatmap import doppler_heatmap, doppler_ratios, required_margin
from mapping.run import Run
from mapping.signal import SonarConfig, tx_period
from mapping.synthetic import Wall, echo_samples, run_motion, run_target, synthetic_run

RESULTS = Path(__file__).resolve().parent / "results"
SPEED = 0.1
REFERENCE_MARGIN = 400


def reference_heatmap(ext: np.ndarray, left: int, speed: float, cfg: SonarConfig) -> np.ndarray:
    """Plain numpy/scipy eq. 1: scipy.signal.resample per ratio, fold, FFT correlation.

    ``resample(seg, num)`` returns ``seg`` at spacing len(seg)/num; the segment length (around
    the block centre) is chosen so that this spacing matches alpha best, and the remaining
    sub-sample misalignment of the output grid is removed by a phase ramp on the folded
    spectrum. Accuracy is limited by the periodic-extension edges of ``resample``. Give it a
    few hundred neighbour samples (``REFERENCE_MARGIN``) so a good length exists.
    """
    b, p, m = cfg.block_samples, cfg.period_samples, cfg.repetitions
    s = tx_period(cfg)
    s_conj = np.conj(np.fft.fft(s))
    c = b // 2
    q = np.fft.fftfreq(p, 1.0 / p)
    rows = []
    for a in doppler_ratios(speed, cfg.angles_rad, cfg.sound_speed_m_s):
        lengths = np.arange(int(np.ceil(a * b)) + 2, ext.size - 1)
        lengths = lengths[(left + c - lengths // 2 >= 0)
                          & (left + c + lengths - lengths // 2 <= ext.size)]
        nums = np.round(lengths / a)
        length = int(lengths[np.argmin(np.abs(lengths / nums - a))])
        num = int(round(length / a))
        s0 = left + c - length // 2
        y = scipy.signal.resample(ext[s0 : s0 + length], num)
        spacing = length / num
        target = left + c - a * c  # ext position of r'[0]
        j0 = int(round((target - s0) / spacing))
        eps = (s0 + j0 * spacing - target) / a  # output grid offset, samples
        r = y[j0 : j0 + b]
        if r.size < b:
            r = np.concatenate([r, np.zeros(b - r.size)])
        folded = np.fft.fft(r.reshape(m, p).sum(axis=0)) * np.exp(-2j * np.pi * q * eps / p)
        h = np.fft.ifft(folded * s_conj).real
        rows.append(np.abs(scipy.signal.hilbert(h)) / (m * np.dot(s, s)))
    return np.array(rows)


def exact_heatmap(run: Run, k: int) -> np.ndarray:
    """Eq. 1 on the echo evaluated from geometry at the stretched times (no interpolation)."""
    cfg = run.config
    b, p, fs = cfg.block_samples, cfg.period_samples, cfg.fs_hz
    s = tx_period(cfg)
    rows = []
    for a in doppler_ratios(float(run.speed_m_s[k]), cfg.angles_rad, cfg.sound_speed_m_s):
        t = (k * b + b / 2 + a * (np.arange(b) - b / 2)) / fs
        r = echo_samples(t, cfg, run_motion(run), run_target(run), spreading=False)
        folded = r.reshape(cfg.repetitions, p).sum(axis=0)
        h = np.fft.irfft(np.fft.rfft(folded) * np.conj(np.fft.rfft(s)), n=p)
        rows.append(np.abs(scipy.signal.hilbert(h)) / (cfg.repetitions * np.dot(s, s)))
    return np.array(rows)


def timed(fn: Callable[[], object], repeats: int) -> dict[str, float]:
    """Median and min wall and CPU seconds of ``fn`` over ``repeats`` calls (after one warm-up)."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return {"wall_median_s": float(np.median(wall)), "wall_min_s": float(np.min(wall)),
            "cpu_median_s": float(np.median(cpu)), "repeats": repeats}


def main() -> int:
    cfg = SonarConfig()
    load_before = os.getloadavg()
    run = synthetic_run(cfg, Wall(2.0, math.radians(35.0)), SPEED, n_blocks=3, spreading=False)
    margin = required_margin(cfg, SPEED)
    ext, left, right = run.neighbourhood(1, margin)
    ref_ext, ref_left, _ = run.neighbourhood(1, REFERENCE_MARGIN)
    exact = exact_heatmap(run, 1)
    peak = float(exact.max())

    def err(h: np.ndarray) -> float:
        return float(np.max(np.abs(h - exact)) / peak)

    def shipped() -> np.ndarray:
        return doppler_heatmap(ext, SPEED, cfg, left=left, right=right).H

    n_threads = numba.get_num_threads()
    ship_t = timed(shipped, 40)
    numba.set_num_threads(1)
    single_t = timed(lambda: doppler_heatmap(ext, SPEED, cfg, left=left, right=right,
                                             workers=1), 40)
    numba.set_num_threads(n_threads)
    ref_t = timed(lambda: reference_heatmap(ref_ext, ref_left, SPEED, cfg), 3)
    ship_err = err(shipped())
    ref_err = err(reference_heatmap(ref_ext, ref_left, SPEED, cfg))

    sweep = []  # single-threaded, so CPU time measures the work itself
    numba.set_num_threads(1)
    plan: tuple[tuple[Literal["spectral", "direct"], tuple[int, ...]], ...] = (
        ("spectral", (4, 6, 8, 12, 16)), ("direct", (2, 8, 16, 32)))
    for method, taps_list in plan:
        for taps in taps_list:
            def f(method: Literal["spectral", "direct"] = method, taps: int = taps) -> np.ndarray:
                return doppler_heatmap(ext, SPEED, cfg, left=left, right=right, method=method,
                                       taps=taps, workers=1).H
            t = timed(f, 10)
            sweep.append({"method": method, "taps": taps, "max_error_of_peak": err(f()),
                          "peak_ratio": float(f().max() / peak), **t})
    numba.set_num_threads(n_threads)
    load_after = os.getloadavg()

    block_s = cfg.block_s
    result: dict[str, Any] = {
        "what": "Doppler heat map per block, Table 1 (B=40920, 30 directions), 0.1 m/s, "
                "wall 2 m at 35 deg; errors are max |H - H_exact| / max H_exact",
        "command": "python -m benchmarks.heatmap",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "numba_threads": n_threads,
                    "numba_threading_layer": numba.threading_layer(),
                    "load_average_before": load_before, "load_average_after": load_after},
        "shipped": {"method": "spectral", "taps": 8, **ship_t, "max_error_of_peak": ship_err,
                    "ms_per_block_wall": 1e3 * ship_t["wall_median_s"],
                    "ms_per_block_cpu": 1e3 * ship_t["cpu_median_s"],
                    "real_time_factor_wall": block_s / ship_t["wall_median_s"]},
        "shipped_one_thread": {**single_t, "ms_per_block_wall": 1e3 * single_t["wall_median_s"],
                               "ms_per_block_cpu": 1e3 * single_t["cpu_median_s"],
                               "real_time_factor_wall": block_s / single_t["wall_median_s"]},
        "reference": {"method": "scipy.signal.resample per ratio + numpy FFT", **ref_t,
                      "max_error_of_peak": ref_err,
                      "ms_per_block_wall": 1e3 * ref_t["wall_median_s"],
                      "real_time_factor_wall": block_s / ref_t["wall_median_s"]},
        "speedup_wall": ref_t["wall_median_s"] / ship_t["wall_median_s"],
        "speedup_one_thread_wall": ref_t["wall_median_s"] / single_t["wall_median_s"],
        "speedup_cpu": ref_t["cpu_median_s"] / ship_t["cpu_median_s"],
        "goal": {"ms_per_block": 5.0, "speedup": 20.0},
        "sweep": sweep,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "heatmap.json").write_text(json.dumps(result, indent=2))
    _plot(result, RESULTS / "heatmap.png")
    print(f"shipped:   {result['shipped']['ms_per_block_wall']:.2f} ms/block wall "
          f"({result['shipped']['ms_per_block_cpu']:.2f} ms CPU), real-time x"
          f"{result['shipped']['real_time_factor_wall']:.0f}, error {ship_err:.1e}")
    print(f"shipped, 1 thread: {1e3 * single_t['wall_median_s']:.2f} ms/block wall "
          f"({1e3 * single_t['cpu_median_s']:.2f} ms CPU), real-time x"
          f"{block_s / single_t['wall_median_s']:.0f}, x"
          f"{result['speedup_one_thread_wall']:.0f} faster than the reference")
    print(f"reference: {result['reference']['ms_per_block_wall']:.1f} ms/block wall, "
          f"error {ref_err:.1e}")
    print(f"speed-up: x{result['speedup_wall']:.0f} wall, x{result['speedup_cpu']:.0f} CPU; "
          f"load average {load_before[0]:.1f} -> {load_after[0]:.1f}")
    return 0


def _plot(result: dict[str, Any], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for method, marker in (("spectral", "o"), ("direct", "s")):
        pts = [s for s in result["sweep"] if s["method"] == method]
        x = [1e3 * s["cpu_median_s"] for s in pts]
        y = [s["max_error_of_peak"] for s in pts]
        ax.plot(x, y, marker=marker, label=f"{method} (taps)")
        for s, xi, yi in zip(pts, x, y, strict=True):
            ax.annotate(str(s["taps"]), (xi, yi), textcoords="offset points", xytext=(4, 4))
    ref = result["reference"]
    ax.plot([1e3 * ref["cpu_median_s"]], [ref["max_error_of_peak"]], "k^",
            label="scipy.signal.resample reference")
    ax.axvline(5.0, color="grey", ls="--", lw=0.8, label="goal 5 ms")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("median CPU time per block, one thread (ms)")
    ax.set_ylabel("max |H - H_exact| / peak")
    ax.set_title("Heat map: time vs accuracy (Table 1, 0.1 m/s)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
