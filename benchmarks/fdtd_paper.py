"""FDTD reference vs image-source engine on the paper scene itself (issue 4, last "Must show").

Scene ``builtin:paper``, path ``paper-a``, one short block whose midpoint is at the paper's
point (a) = (2, 2). Two cases (all choices are in the JSON):

1. The paper's signal (Table 1: L = 1023, fc = chip rate = 10 kHz, fs = 40 kHz) with M = 2
   repetitions (block 0.2046 s) at 0.5 m/s (M = 2 at 0.5 m/s keeps the paper's Doppler drift
   of 24 samples and its 0.1023 m per block), on Table 2's grid (dx = 5 mm, dt = 8.333 us);
   injected band 17 kHz (4 points per wavelength, the FDTD default). Only 6.8 points per
   wavelength at the carrier: the echoes are dispersed by 2-8 % and smeared into several
   lobes.
2. A scaled signal (fc = chip rate = 2.5 kHz, fs = 10 kHz, L = 127, M = 4: block 0.2032 s,
   one-way unambiguous range 8.6 m) at 1 m/s (Doppler drift 12 samples, as the one-wall
   comparison of benchmarks/fdtd.py) on a 1 cm grid (dt = 16.67 us, Courant 0.567): 13.6
   points per wavelength at the carrier.

Both: FDTD warm-up 0.08 s, and the image-source engine is limited to round-trip paths
<= c * 0.08 s = 27.2 m so both engines hear the same set of paths.
- Image-source engine: spreading "2d" (the 2-D FDTD's line source), automatic order.
- Band and dispersion: every echo of the FDTD has travelled its whole path through the
  grid, so it is late by the grid's dispersion along its own direction. The image-source
  block is rebuilt path by path from its path table (delay and Doppler factor at the block
  midpoint, amplitude, 2-D signal period), band-limited by the FDTD's injection tapers, with
  the phase ``exp(-i (k_num(f, phi) - k) L)`` of each path (length L = c delay, direction
  phi of its image), the same correction benchmarks/fdtd.py applies to its one-wall scene
  with one path. The rebuild without the phase is checked against the engine's own block
  (correlation in the JSON).

Heat maps of both (``mapping.heatmap.doppler_heatmap``), their global peaks and strongest
local peaks, and a figure with both maps, their difference and the two free wall ends, where
the FDTD diffracts and the image-source model does not. Writes
benchmarks/results/fdtd_paper.json and fdtd_paper.png. About 40 s on 2 cores.
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
_HERE = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
sys.path.insert(0, str(_HERE.parent))

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from mapping.heatmap import HeatMap, doppler_heatmap, find_peak  # noqa: E402
from mapping.path import builtin_path  # noqa: E402
from mapping.scene import builtin_scene  # noqa: E402
from mapping.signal import SonarConfig  # noqa: E402
from mapping.simulate.fdtd import (  # noqa: E402
    FdtdConfig,
    finished_blocks,
    injected_band,
    iter_fdtd,
    new_state,
    numerical_group_velocity,
    numerical_wavenumber,
    setup_for_scene,
)
from mapping.simulate.fdtd_dispersion import source_filter  # noqa: E402
from mapping.simulate.ism import IsmConfig, iter_ism_blocks, signal_period  # noqa: E402

OUT = Path(__file__).resolve().parent / "results"
C = 340.0
#: (name, signal, speed m/s, grid step m, time step s); Courant 0.567 in both
CASES: tuple[tuple[str, SonarConfig, float, float, float], ...] = (
    ("paper signal, Table 2 grid (5 mm)", SonarConfig(repetitions=2), 0.5, 0.005, 8.333e-6),
    ("scaled signal (fc 2.5 kHz, L 127, M 4), 1 cm grid",
     SonarConfig(sequence_length=127, carrier_hz=2500.0, chip_rate_hz=2500.0, fs_hz=10_000.0,
                 repetitions=4), 1.0, 0.01, 1.6667e-5),
)
WARMUP_S = 0.08
POINT_A = (2.0, 2.0)
FREE_ENDS = {"wall 1 free end (0.5, 4)": (0.5, 4.0), "wall 3 free end (2.3, 1.36)": (2.3, 1.36)}
OVERSAMPLE = 32
RMAX_M = 5.0


def _block_index(sonar: SonarConfig, speed_m_s: float) -> int:
    """Block whose midpoint lies nearest point (a) on paper-a (starts at (1, 1), heading pi/4)."""
    along = float(np.hypot(POINT_A[0] - 1.0, POINT_A[1] - 1.0))
    return int(round(along / (speed_m_s * sonar.block_s) - 0.5))


def _path_phase(f_hz: NDArray[np.float64], length_m: float, angle_rad: float,
                f_max_hz: float, fdtd: FdtdConfig) -> NDArray[np.complex128]:
    """Grid-dispersion phase of one path: exp(-i (k_num - k) L) below ``f_max_hz``."""
    k = 2 * np.pi * f_hz / C
    kn = np.array([numerical_wavenumber(fi, angle_rad, fdtd.grid_step_m,
                                        fdtd.time_step_s, C)
                   if 0 < fi < f_max_hz else ki for fi, ki in zip(f_hz, k, strict=True)])
    out: NDArray[np.complex128] = np.exp(-1j * (kn - k) * length_m)
    return out


def grid_band(f_hz: NDArray[np.float64], sonar: SonarConfig,
              fdtd: FdtdConfig) -> NDArray[np.float64]:
    """The FDTD's injection tapers (high-pass below 0.1 f_c, raised-cosine low-pass to the
    grid's band edge), read off :func:`source_filter` without its 1/(i w) and gain."""
    g = np.abs(source_filter(f_hz, sonar, fdtd) * 2 * np.pi * f_hz)
    out: NDArray[np.float64] = g / g.max()
    return out


def render_paths(block: Any, sonar: SonarConfig, heading_rad: float, k: int,
                 dispersion: bool, fdtd: FdtdConfig) -> NDArray[np.float64]:
    """Block ``k`` rebuilt path by path from the image-source path table.

    Path i: ``a_i s2d(t - tau_i(t))`` with ``tau_i(t) = tau_i + (1 - D_i)(t - t_mid)`` (delay
    and Doppler factor at the midpoint), ``s2d`` the 2-D signal period on a 32x finer grid,
    band-limited by the FDTD's injection tapers (:func:`grid_band`) and optionally with the
    grid-dispersion phase of its length and direction applied first.
    """
    period = signal_period(sonar, "2d")
    p = period.size
    f: NDArray[np.float64] = np.fft.rfftfreq(p, 1.0 / sonar.fs_hz).astype(np.float64)
    spec: NDArray[np.complex128] = np.fft.rfft(period) * grid_band(f, sonar, fdtd)
    _, f_max_hz = injected_band(sonar, fdtd)
    B = sonar.block_samples
    fs = sonar.fs_hz
    t = (k * B + np.arange(B)) / fs
    t_mid = (k + 0.5) * B / fs
    out = np.zeros(B)
    paths = block.paths
    for i in range(paths.delay_s.size):
        s = spec
        if dispersion:
            # heading pi/4: the +-theta ambiguity is a mirror about the diagonal, which leaves
            # the grid's dispersion unchanged
            phi = heading_rad + float(paths.angle_to_velocity_rad[i])
            s = np.multiply(spec, _path_phase(f, C * float(paths.delay_s[i]), phi, f_max_hz,
                                              fdtd))
        fine = np.fft.irfft(s, n=p * OVERSAMPLE) * OVERSAMPLE
        tau = paths.delay_s[i] + (1.0 - paths.doppler_factor[i]) * (t - t_mid)
        pos = ((t - tau) * fs * OVERSAMPLE) % (p * OVERSAMPLE)
        i0 = np.floor(pos).astype(np.int64)
        w = pos - i0
        i1 = (i0 + 1) % (p * OVERSAMPLE)
        out += paths.amplitude[i] * ((1 - w) * fine[i0] + w * fine[i1])
    return out


def _corr(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    return float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))


def local_peaks(hm: HeatMap, n: int, max_range_m: float) -> list[dict[str, float]]:
    """The ``n`` strongest local maxima (3x3 neighbourhood, range circular) below a range."""
    H = hm.H[:, : int(np.searchsorted(hm.ranges_m, max_range_m))]
    pad = np.pad(H, ((1, 1), (0, 0)), mode="reflect")
    nb = np.stack([np.roll(pad, (di, dj), axis=(0, 1))[1:-1]
                   for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)])
    is_max = H > nb.max(axis=0)
    idx = np.argwhere(is_max)
    vals = H[is_max]
    order = np.argsort(vals)[::-1][:n]
    top = float(H.max())
    return [{"n_theta": int(idx[j, 0]), "n_tau": int(idx[j, 1]),
             "range_m": float(hm.ranges_m[idx[j, 1]]),
             "angle_deg": float(np.degrees(hm.angles_rad[idx[j, 0]])),
             "rel_db": float(20 * np.log10(vals[j] / top))} for j in order]


def _peak(hm: HeatMap) -> dict[str, float]:
    pk = find_peak(hm)
    return {"n_tau": pk.n_tau, "n_theta": pk.n_theta, "range_m": pk.range_m,
            "angle_deg": float(np.degrees(pk.angle_rad))}


def _agree(a: dict[str, float], b: dict[str, float]) -> dict[str, Any]:
    d_tau, d_theta = abs(a["n_tau"] - b["n_tau"]), abs(a["n_theta"] - b["n_theta"])
    return {"d_range_bins": int(d_tau), "d_angle_bins": int(d_theta),
            "agree_within_one_bin": bool(d_tau <= 1 and d_theta <= 1)}


def echo_peaks(maps: dict[str, HeatMap], paths: Any, heading_rad: float, n: int,
               sonar: SonarConfig, fdtd: FdtdConfig, speed_m_s: float,
               window_m: float = 0.15) -> list[dict[str, Any]]:
    """Echo by echo: the ``n`` strongest image-source paths, each searched in every map within
    +-``window_m`` of its dispersion-predicted range (carrier group velocity along its
    direction) and +-2 angle bins of its heat-map angle (from its Doppler factor); the
    maximum cell of each map is reported.

    A dispersed broadband echo has several lobes of nearly equal height (the grid's group
    delay grows with frequency), so the global maximum of a map may jump between lobes; the
    echo-wise comparison is the robust one.
    """
    hm = maps["fdtd"]
    step = float(hm.ranges_m[1])
    out = []
    for i in np.argsort(-np.abs(paths.amplitude))[:n]:
        # heat-map angle of a path: its Doppler factor D = 1 + 2 v cos(theta) / c (the mean
        # of the departure and arrival cosines; = the arrival angle only for a path that
        # returns along itself)
        cos_eff = (float(paths.doppler_factor[i]) - 1.0) * C / (2 * speed_m_s)
        theta = float(np.arccos(np.clip(cos_eff, -1.0, 1.0)))
        phi = heading_rad + float(paths.angle_to_velocity_rad[i])
        r = C * float(paths.delay_s[i]) / 2
        vg = numerical_group_velocity(sonar.carrier_hz, phi, fdtd.grid_step_m,
                                      fdtd.time_step_s, C)
        r_pred = r * C / vg
        j0, j1 = int((r_pred - window_m) / step), int((r_pred + window_m) / step) + 1
        a = int(np.argmin(np.abs(hm.angles_rad - theta)))
        a0, a1 = max(a - 2, 0), min(a + 3, hm.angles_rad.size)
        row: dict[str, Any] = {"walls": list(paths.walls[i]), "true_range_m": r,
                               "predicted_fdtd_range_m": r_pred,
                               "heatmap_angle_deg": float(np.degrees(theta)),
                               "arrival_angle_deg": float(np.degrees(phi - heading_rad))}
        for name, m in maps.items():
            sub = m.H[a0:a1, j0:j1]
            it, jt = np.unravel_index(int(np.argmax(sub)), sub.shape)
            row[name] = {"n_theta": int(a0 + it), "n_tau": int(j0 + jt),
                         "range_m": float(m.ranges_m[j0 + jt])}
        row["agreement_fdtd_vs_ism_dispersed"] = _agree(row["fdtd"], row["ism_dispersed"])
        out.append(row)
    return out


def _residual_near(maps: dict[str, HeatMap], r_m: float, theta_rad: float,
                   window_m: float = 0.15) -> dict[str, float]:
    """Largest |FDTD - image source| (maps normalised to their maxima below RMAX_M) within
    +-``window_m`` and +-2 angle bins of a point, and the 99th percentile of |difference|."""
    hm = maps["fdtd"]
    n = int(np.searchsorted(hm.ranges_m, RMAX_M))
    d = np.abs(hm.H[:, :n] / hm.H[:, :n].max()
               - maps["ism_dispersed"].H[:, :n] / maps["ism_dispersed"].H[:, :n].max())
    a = int(np.argmin(np.abs(hm.angles_rad - theta_rad)))
    j0, j1 = np.searchsorted(hm.ranges_m, [r_m - window_m, r_m + window_m])
    near = d[max(a - 2, 0): a + 3, j0:j1]
    return {"max_abs_residual_near": float(near.max()),
            "p99_abs_residual_whole_map": float(np.percentile(d, 99)),
            "max_abs_residual_whole_map": float(d.max())}


def run_case(name: str, sonar: SonarConfig, speed_m_s: float, grid_step_m: float,
             time_step_s: float) -> tuple[dict[str, Any], dict[str, HeatMap]]:
    """Both engines on the block of paper-a nearest point (a); numbers and heat maps."""
    scene = builtin_scene("paper")
    traj = builtin_path("paper-a", speed_m_s=speed_m_s)
    k = _block_index(sonar, speed_m_s)
    t_mid = (k + 0.5) * sonar.block_s
    pos = traj.position(np.array([t_mid]))[0]
    heading = float(traj.heading_rad(np.array([t_mid]))[0])

    ism_cfg = IsmConfig(spreading="2d", max_path_m=C * WARMUP_S)
    t0 = time.perf_counter()
    block = next(iter(iter_ism_blocks(scene, traj, sonar, 1, ism_cfg,
                                      np.random.default_rng(0), first_block=k)))
    ism_s = time.perf_counter() - t0
    x_ism = np.asarray(block.samples, dtype=float)

    fdtd_cfg = FdtdConfig(grid_step_m=grid_step_m, time_step_s=time_step_s, warmup_s=WARMUP_S)
    _, f_max = injected_band(sonar, fdtd_cfg)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        setup = setup_for_scene(scene, traj, sonar, fdtd_cfg, n_blocks=1, first_block=k)
    state = new_state(setup)
    for _ in iter_fdtd(setup, state):
        pass
    x_fdtd = np.asarray(finished_blocks(setup, state)[0].samples, dtype=float)
    fdtd_s = time.perf_counter() - t0

    x_rebuilt = render_paths(block, sonar, heading, k, False, fdtd_cfg)
    x_disp = render_paths(block, sonar, heading, k, True, fdtd_cfg)

    maps = {"fdtd": doppler_heatmap(x_fdtd, speed_m_s, sonar),
            "ism": doppler_heatmap(x_ism, speed_m_s, sonar),
            "ism_dispersed": doppler_heatmap(x_disp, speed_m_s, sonar)}
    peaks = {nm: _peak(hm) for nm, hm in maps.items()}
    res: dict[str, Any] = {
        "case": name, "scene": "builtin:paper", "path": "paper-a", "block_index": k,
        "block_mid_position_m": pos.tolist(), "heading_deg": float(np.degrees(heading)),
        "choices": {"sequence_length": sonar.sequence_length, "carrier_hz": sonar.carrier_hz,
                    "chip_rate_hz": sonar.chip_rate_hz, "fs_hz": sonar.fs_hz,
                    "repetitions_M": sonar.repetitions, "speed_m_s": speed_m_s,
                    "block_s": sonar.block_s,
                    "doppler_drift_samples": 2 * speed_m_s * sonar.block_samples / C,
                    "grid_step_m": grid_step_m, "time_step_s": time_step_s,
                    "courant": C * time_step_s / grid_step_m, "fdtd_warmup_s": WARMUP_S,
                    "injected_band_hz": f_max, "fdtd_grid": list(setup.grid.shape),
                    "fdtd_steps": setup.n_steps,
                    "ism": {"spreading": "2d", "order": "auto",
                            "max_path_m": C * WARMUP_S, "n_paths": int(block.paths.delay_s.size),
                            "max_order": int(block.paths.order.max())}},
        "correlation": {"fdtd_vs_ism_raw": _corr(x_fdtd, x_ism),
                        "fdtd_vs_ism_band_limited_no_dispersion": _corr(x_fdtd, x_rebuilt),
                        "fdtd_vs_ism_dispersion_corrected": _corr(x_fdtd, x_disp),
                        "band_limited_rebuild_vs_ism_engine": _corr(x_rebuilt, x_ism)},
        "energy_ratio_fdtd_over_ism_dispersed": float(np.sum(x_fdtd**2) / np.sum(x_disp**2)),
        "peaks": peaks,
        "agreement_fdtd_vs_ism_dispersed": _agree(peaks["fdtd"], peaks["ism_dispersed"]),
        "agreement_fdtd_vs_ism_raw": _agree(peaks["fdtd"], peaks["ism"]),
        "echoes": echo_peaks(maps, block.paths, heading, 6, sonar, fdtd_cfg, speed_m_s),
        "local_peaks": {nm: local_peaks(hm, 6, RMAX_M) for nm, hm in maps.items()},
        "bins": {"range_bin_m": float(maps["fdtd"].ranges_m[1]),
                 "angle_bin_deg": float(np.degrees(maps["fdtd"].angles_rad[1]))},
        "free_ends": {}, "seconds": {"ism_block": ism_s, "fdtd_block": fdtd_s},
    }
    vel = np.array([np.cos(heading), np.sin(heading)])
    for fe_name, xy in FREE_ENDS.items():
        d = np.array(xy) - pos
        r = float(np.hypot(*d))
        ang = float(np.degrees(np.arccos(np.clip(np.dot(d, vel) / r, -1, 1))))
        res["free_ends"][fe_name] = {"range_m": r, "angle_deg": ang,
                                     **_residual_near(maps, r, np.radians(ang))}
    print(json.dumps({kk: res[kk] for kk in ("case", "correlation", "peaks",
                                              "agreement_fdtd_vs_ism_dispersed",
                                              "seconds")}, indent=1))
    return res, maps


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    t_wall = time.perf_counter()
    out: dict[str, Any] = {"load_average_start": os.getloadavg(), "cases": []}
    all_maps = []
    for case in CASES:
        res, maps = run_case(*case)
        out["cases"].append(res)
        all_maps.append(maps)
    _plot(all_maps, out["cases"])
    out["load_average_end"] = os.getloadavg()
    out["total_wall_s"] = time.perf_counter() - t_wall
    (OUT / "fdtd_paper.json").write_text(json.dumps(out, indent=2))
    print("total wall seconds", out["total_wall_s"])


def _plot(all_maps: list[dict[str, HeatMap]], cases: list[dict[str, Any]]) -> None:
    fig = plt.figure(figsize=(15, 4.6 * len(cases)), layout="constrained")
    subs = fig.subfigures(len(cases), 1, squeeze=False)[:, 0]
    for sub, maps, res in zip(subs, all_maps, cases, strict=True):
        row = sub.subplots(1, 3, sharey=True)
        hm = maps["fdtd"]
        n = int(np.searchsorted(hm.ranges_m, RMAX_M))
        a = hm.H[:, :n] / hm.H[:, :n].max()
        b = maps["ism_dispersed"].H[:, :n] / maps["ism_dispersed"].H[:, :n].max()
        ext = (0, float(hm.ranges_m[n - 1]), 0, 180)
        dx_cm = res["choices"]["grid_step_m"] * 100
        panels = ((a, f"FDTD, {dx_cm:g} cm grid", "viridis", (0, 1)),
                  (b, "image source (2d), band + grid dispersion applied", "viridis", (0, 1)),
                  (a - b, "FDTD - image source", "RdBu_r", (-0.5, 0.5)))
        for axi, (img, title, cmap, (lo, hi)) in zip(row, panels, strict=True):
            im = axi.imshow(img, aspect="auto", origin="lower", extent=ext, cmap=cmap,
                            vmin=lo, vmax=hi, interpolation="nearest")
            axi.set_title(title, fontsize=9)
            axi.set_xlabel("range (m)")
            sub.colorbar(im, ax=axi)
            for (name, fe), m in zip(res["free_ends"].items(), ("s", "D"), strict=True):
                axi.plot(fe["range_m"], fe["angle_deg"], m, mfc="none", mec="magenta", ms=14,
                         mew=1.5, label=f"diffraction: {name}")
            for key, col in (("fdtd", "red"), ("ism_dispersed", "orange")):
                pk = res["peaks"][key]
                axi.plot(pk["range_m"], pk["angle_deg"], "+", color=col, ms=12, mew=1.5,
                         label=f"global peak {key}")
        row[2].legend(fontsize=6, loc="upper left", framealpha=0.6)
        row[0].set_ylabel("angle to velocity (deg)")
        c = res["correlation"]
        ag = res["agreement_fdtd_vs_ism_dispersed"]
        ch = res["choices"]
        sub.suptitle(f"{res['case']}: v = {ch['speed_m_s']:g} m/s, block "
                     f"{ch['block_s']:.3f} s at ({res['block_mid_position_m'][0]:.2f}, "
                     f"{res['block_mid_position_m'][1]:.2f}); waveform corr raw "
                     f"{c['fdtd_vs_ism_raw']:.3f}, dispersion-corrected "
                     f"{c['fdtd_vs_ism_dispersion_corrected']:.3f}; global peaks differ by "
                     f"{ag['d_range_bins']} range / {ag['d_angle_bins']} angle bins",
                     fontsize=9)
    fig.savefig(OUT / "fdtd_paper.png", dpi=110)


if __name__ == "__main__":
    main()
