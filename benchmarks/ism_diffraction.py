"""Edge diffraction in the image-source engine against the FDTD reference (issue 15 item 2).

1. **FDTD vs image source, with and without diffraction.** Two small scenes, a static sonar,
   the scaled signal of the FDTD comparisons (fc = chip rate = 2.5 kHz, fs = 10 kHz, L = 31,
   M = 2), a 5 mm grid (27 points per wavelength at the carrier, so the grid's dispersion
   is small on these <= 3 m paths and is not corrected), 0.02 s warm-up; the image-source
   engine with ``spreading="2d"`` and paths up to c * 0.02 s = 6.8 m, band-limited like the
   FDTD's source (``mapping.compare.band_limited``). Scenes: one free-standing 1 m wall
   (free ends (0, 0.5) and (1, 0.5)) and an outside corner (two 1 m walls meeting at the
   origin, the sonar on the 270 deg side); per scene a position where only diffraction is
   heard (the specular points lie off the walls) and one where specular echoes are heard
   too. Residual energy ``|FDTD - ISM|^2 / |FDTD|^2`` (no fitted scale) for
   ``diffraction_order`` 0, 1, 2, and the delay of the FDTD relative to the image-source
   block at the largest cross-correlation (the diffracted arrival where only it is heard).
2. **Cost and which scenes need it.** Every built-in scene on its first built-in path,
   default signal (Table 1, M = 10), ``spreading="3d"``, fixed order 3, three blocks along
   the path: milliseconds per block (median, after a warm-up, same process) with diffraction
   off and at orders 1 and 2, and the energy of the diffracted part (order-2 block minus the
   block without) relative to the specular block, in dB.

Writes benchmarks/results/ism_diffraction.json and ism_diffraction.png. About 1.5 min on 2
cores (the four 5 mm FDTD runs dominate).
"""

from __future__ import annotations

import json
import os
import time
import warnings
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from mapping.compare import band_limited, lag_s, residual_energy
from mapping.path import builtin_path, builtin_path_names, builtin_path_scene, stationary_path
from mapping.scene import Scene, Wall, builtin_scene, builtin_scene_names
from mapping.signal import SonarConfig, tx_period
from mapping.simulate import simulate_run
from mapping.simulate.fdtd import FdtdConfig, simulate_fdtd
from mapping.simulate.ism import IsmConfig, plan_stretch, prepare_scene, render_stretch

matplotlib.use("Agg")
OUT = Path(__file__).resolve().parent / "results"
C = 340.0
SCALED = SonarConfig(sequence_length=31, carrier_hz=2500.0, chip_rate_hz=2500.0,
                     fs_hz=10_000.0, repetitions=2)
GRID_STEP_M = 0.005
WARMUP_S = 0.02
FREE_END = Scene(name="free end", walls=[Wall(start=(0.0, 0.5), end=(1.0, 0.5))])
CORNER = Scene(name="outside corner", walls=[Wall(start=(0.0, 0.0), end=(1.0, 0.0)),
                                             Wall(start=(0.0, 0.0), end=(0.0, 1.0))])
#: (label, scene, static sonar position)
CASES: tuple[tuple[str, Scene, tuple[float, float]], ...] = (
    ("free end, shadow: edges only", FREE_END, (-0.3, 0.1)),
    ("free end, lit: specular + edges", FREE_END, (0.35, 0.1)),
    ("outside corner: edges only", CORNER, (-0.4, -0.3)),
    ("outside corner, lit: specular + edges", CORNER, (-0.3, 0.35)),
)
ORDERS = (0, 1, 2)


def fdtd_config() -> FdtdConfig:
    return FdtdConfig(grid_step_m=GRID_STEP_M, time_step_s=0.567 * GRID_STEP_M / C,
                      pml_cells=20, margin_m=0.3, warmup_s=WARMUP_S)


def ism_block(scene: Scene, xy: tuple[float, float], order: int) -> np.ndarray:
    traj = stationary_path(np.array(xy), 0.0, 10.0)
    engine = IsmConfig(spreading="2d", max_path_m=C * WARMUP_S, diffraction_order=order)
    run = simulate_run(scene, traj, SCALED, 1, engine, np.random.default_rng(0))
    return np.asarray(run.samples[0], dtype=np.float64)


def compare_case(label: str, scene: Scene, xy: tuple[float, float]) -> dict[str, Any]:
    """FDTD vs the image-source engine at diffraction orders 0-2 on one static position."""
    cfg = fdtd_config()
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fdtd = simulate_fdtd(scene, stationary_path(np.array(xy), 0.0, 10.0), SCALED, cfg,
                             n_blocks=1).samples[0].astype(float)
    seconds = time.perf_counter() - t
    out: dict[str, Any] = {"label": label, "scene": scene.name, "position_m": list(xy),
                           "fdtd_seconds": seconds, "orders": {}}
    for order in ORDERS:
        ism = band_limited(ism_block(scene, xy, order), SCALED, cfg)
        silent = not np.any(ism)
        lag = float("nan") if silent else lag_s(fdtd, ism, SCALED.fs_hz, 2e-3)
        corr = 0.0 if silent else float(fdtd @ ism / np.linalg.norm(fdtd) / np.linalg.norm(ism))
        out["orders"][str(order)] = {
            "residual_energy": residual_energy(fdtd, ism),
            "correlation": corr,
            "energy_ratio_ism_over_fdtd": float(ism @ ism / (fdtd @ fdtd)),
            "lag_s": lag, "lag_m_round_trip": lag * C,
        }
    out["waveforms"] = {"fdtd": fdtd, **{str(o): band_limited(ism_block(scene, xy, o), SCALED,
                                                               cfg) for o in (0, 2)}}
    return out


def _block_ms(scene: Scene, path: str, engine: IsmConfig, blocks: list[int]
              ) -> tuple[list[float], list[np.ndarray]]:
    sonar = SonarConfig()
    traj = builtin_path(path)
    prepared = prepare_scene(scene, sonar, engine)
    B = sonar.block_samples
    times, samples = [], []
    for k in blocks:
        t = time.perf_counter()
        plan = plan_stretch(prepared, traj, sonar, engine, k * B, B)
        samples.append(render_stretch(plan, sonar, engine))
        times.append((time.perf_counter() - t) * 1e3)
    return times, samples


def scene_costs() -> list[dict[str, Any]]:
    """Per built-in scene: ms per block without and with diffraction, diffracted energy."""
    rows = []
    for name in builtin_scene_names():
        path = next(p for p in builtin_path_names() if builtin_path_scene(p) == name)
        n_blocks = int(builtin_path(path).duration_s / SonarConfig().block_s)
        blocks = [int(round(f * (n_blocks - 1))) for f in (0.2, 0.5, 0.8)]
        scene = builtin_scene(name)
        row: dict[str, Any] = {"scene": name, "path": path, "blocks": blocks}
        base: list[np.ndarray] = []
        for order in ORDERS:
            engine = IsmConfig(order=3, diffraction_order=order)
            _block_ms(scene, path, engine, blocks[:1])  # warm-up (numba, caches)
            times, samples = _block_ms(scene, path, engine, blocks)
            row[f"ms_per_block_d{order}"] = float(np.median(times))
            if order == 0:
                base = samples
            else:
                diff = sum(float(np.sum((s - b) ** 2)) for s, b in zip(samples, base,
                                                                       strict=True))
                spec = sum(float(np.sum(b**2)) for b in base)
                # None: nothing diffracted is heard (closed rooms: no outside corner or free
                # end faces the sonar)
                row[f"diffracted_db_d{order}"] = (float(10 * np.log10(diff / spec))
                                                  if diff > 0 else None)
        row["cost_ratio_d2"] = row["ms_per_block_d2"] / row["ms_per_block_d0"]
        print(row, flush=True)
        rows.append(row)
    return rows


def _envelope(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Matched-filter envelope of one period (summed over the block's periods) vs round-trip
    path length in metres."""
    p = SCALED.period_samples
    y = x.reshape(-1, p).sum(axis=0)
    spec = np.fft.rfft(y) * np.conj(np.fft.rfft(tx_period(SCALED)))
    up = 8
    full = np.zeros(p * up, dtype=complex)
    full[: spec.size] = 2 * spec
    env = np.abs(np.fft.ifft(full)) * up
    return np.arange(p * up) / up / SCALED.fs_hz * C, env


def plot(cases: list[dict[str, Any]], rows: list[dict[str, Any]]) -> None:
    fig, axs = plt.subplots(2, 2, figsize=(12, 7.5))
    for ax, case in zip(axs[0], (cases[0], cases[2]), strict=True):
        w = case["waveforms"]
        for key, style, label in (("fdtd", "k-", "FDTD (5 mm)"),
                                  ("0", "C1--", "image source"),
                                  ("2", "C0-", "image source + diffraction")):
            r, env = _envelope(w[key])
            ax.plot(r, env, style, lw=1.2, label=label)
        ax.set_xlim(0, 3.5)
        ax.set_xlabel("round-trip path (m)")
        ax.set_ylabel("matched-filter envelope")
        res = case["orders"]
        ax.set_title(f"{case['label']} at {tuple(case['position_m'])}\nresidual energy "
                     f"{res['0']['residual_energy']:.2f} -> {res['2']['residual_energy']:.3f}",
                     fontsize=9)
        ax.legend(fontsize=7)
    ax = axs[1, 0]
    x = np.arange(len(cases))
    for j, order in enumerate(ORDERS):
        ax.bar(x + (j - 1) * 0.27, [c["orders"][str(order)]["residual_energy"] for c in cases],
               0.27, label=f"diffraction_order {order}")
    ax.set_xticks(x, [c["label"].replace(": ", ":\n") for c in cases], fontsize=7)
    ax.set_yscale("log")
    ax.set_ylabel("|FDTD - ISM|^2 / |FDTD|^2")
    ax.set_title("residual energy against the FDTD (static sonar, 2-D)", fontsize=9)
    ax.legend(fontsize=7)
    ax = axs[1, 1]
    names = [row["scene"] for row in rows]
    y = np.arange(len(rows))
    db = [-60.0 if row["diffracted_db_d2"] is None else row["diffracted_db_d2"] for row in rows]
    ax.barh(y, [d + 60 for d in db], left=-60, color="C2")
    for yi, row, d in zip(y, rows, db, strict=True):
        heard = "none heard" if row["diffracted_db_d2"] is None else f"{d:.1f} dB"
        ax.annotate(f"{heard}; {row['ms_per_block_d0']:.0f} -> {row['ms_per_block_d2']:.0f} "
                    f"ms/block (x{row['cost_ratio_d2']:.2f})", (-59, yi), va="center",
                    fontsize=7, color="k")
    ax.set_yticks(y, names)
    ax.set_xlabel("diffracted energy / specular energy (dB), 3d, order 3, 3 blocks")
    ax.set_title("which built-in scenes need diffraction, and its cost", fontsize=9)
    ax.set_xlim(-60, 0)
    fig.tight_layout()
    fig.savefig(OUT / "ism_diffraction.png", dpi=120)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    res: dict[str, Any] = {"load_average_start": os.getloadavg(), "cpus": os.cpu_count(),
                           "grid_step_m": GRID_STEP_M, "warmup_s": WARMUP_S}
    cases: list[dict[str, Any]] = []
    for label, scene, xy in CASES:
        found = compare_case(label, scene, xy)
        print(label, {k: {kk: round(vv, 4) for kk, vv in v.items()}
                      for k, v in found["orders"].items()}, flush=True)
        cases.append(found)
    rows = scene_costs()
    plot(cases, rows)
    res["cases"] = [{k: v for k, v in c.items() if k != "waveforms"} for c in cases]
    res["sonar"] = {"sequence_length": SCALED.sequence_length, "carrier_hz": SCALED.carrier_hz,
                    "chip_rate_hz": SCALED.chip_rate_hz, "fs_hz": SCALED.fs_hz,
                    "repetitions": SCALED.repetitions}
    res["scenes"] = rows
    res["load_average_end"] = os.getloadavg()
    res["wall_s"] = time.perf_counter() - t0
    (OUT / "ism_diffraction.json").write_text(json.dumps(res, indent=2, default=str))


if __name__ == "__main__":
    main()
