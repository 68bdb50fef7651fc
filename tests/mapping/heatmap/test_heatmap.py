"""Tests of mapping.heatmap against the analytic echo of mapping.synthetic (paper eq. 1).

Truths used: the geometric two-way delay and angle of a wall / point (synthetic), the exactly
resampled echo evaluated from geometry at the stretched times (no interpolation), and the
plain numpy twins of the numba kernels (naive.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import hilbert

from mapping.heatmap import (
    STRIP_STEP_RAD,
    HeatMap,
    bank_angles,
    doppler_heatmap,
    doppler_ratios,
    find_peak,
    heatmap_of_run,
    polyphase_table,
    required_margin,
    resample_about_centre,
)
from mapping.heatmap._kernels import (  # only to compare the kernels with their twins
    _resample_fold,
    _spectral_bank,
    _SpectralGrid,
    _Window,
)
from mapping.run import Run
from mapping.signal import SonarConfig, transmitted_at, tx_period
from mapping.synthetic import (
    PointReflector,
    Wall,
    echo_samples,
    run_motion,
    run_target,
    run_truth,
    synthetic_run,
)
from tests.mapping.heatmap import naive

CFG = SonarConfig()  # Table 1, M = 10
SMALL = SonarConfig(sequence_length=63, repetitions=4)  # B = 1008, for property tests
V = 0.1
HALF_BIN_DEG = 180.0 / CFG.directions / 2.0  # 3.1 deg
RANGE_SAMPLE_M = CFG.range_per_sample_m  # 4.25 mm


@lru_cache(maxsize=64)
def wall_run(distance_m: float, theta_deg: float, speed: float = V, m: int = 10) -> Run:
    cfg = SonarConfig(repetitions=m)
    return synthetic_run(cfg, Wall(distance_m, math.radians(theta_deg)), speed, n_blocks=3)


# ---- range and angle against geometry -----------------------------------------------------
@pytest.mark.parametrize("distance_m", [0.5, 1.0, 2.0, 4.0, 8.0])
@pytest.mark.parametrize("theta_deg", [20.0, 60.0, 160.0])
def test_peak_range_within_one_sample(distance_m: float, theta_deg: float) -> None:
    run = wall_run(distance_m, theta_deg)
    peak = find_peak(heatmap_of_run(run, 1))
    truth = run_truth(run, 1)
    # truth: c * tau / 2 of the echo received at the block midpoint (the pose time). A map
    # resampled about the block start would be off by v T / 2 cos(theta) (up to 48 mm here).
    assert abs(peak.range_m - truth.range_m) <= RANGE_SAMPLE_M
    assert abs(truth.range_m - distance_m) < 0.01


@pytest.mark.parametrize(
    "theta_deg", [20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 110.0, 120.0, 130.0, 140.0, 150.0, 160.0]
)
def test_peak_angle_within_half_a_bin(theta_deg: float) -> None:
    run = wall_run(2.0, theta_deg)
    peak = find_peak(heatmap_of_run(run, 1))
    assert abs(math.degrees(peak.angle_rad) - theta_deg) <= HALF_BIN_DEG


def test_resampling_direction_is_not_backwards_at_40_deg() -> None:
    # A backwards resampling (by beta = 1/alpha) maps theta -> 180 - theta: 40 -> 140 deg.
    hm = heatmap_of_run(wall_run(2.0, 40.0), 1)
    peak = find_peak(hm)
    assert abs(math.degrees(peak.angle_rad) - 40.0) <= HALF_BIN_DEG
    col = hm.H[:, peak.n_tau]
    row_140 = int(np.argmin(np.abs(hm.angles_rad - math.radians(140.0))))
    assert col[row_140] < 0.1 * col.max()


def test_point_reflector_range_and_angle() -> None:
    run = synthetic_run(CFG, PointReflector(3.0, math.radians(-65.0)), V, n_blocks=3)
    peak = find_peak(heatmap_of_run(run, 1))
    truth = run_truth(run, 1)
    assert abs(peak.range_m - truth.range_m) <= RANGE_SAMPLE_M
    assert abs(math.degrees(peak.angle_rad) - 65.0) <= HALF_BIN_DEG


def test_mirror_wall_gives_the_same_map() -> None:
    a = heatmap_of_run(wall_run(2.0, 50.0), 1).H
    b = heatmap_of_run(wall_run(2.0, -50.0), 1).H
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-6 * a.max())


def test_unit_echo_peak_amplitude_is_about_one() -> None:
    run = synthetic_run(CFG, Wall(2.0, math.radians(2 * 180 / 29 * 3)), V, n_blocks=3,
                        spreading=False)  # wall exactly on bin 6 of the bank
    # H is sampled at integer lags; a fractional delay costs the envelope a little (< 3 %)
    assert find_peak(heatmap_of_run(run, 1)).value == pytest.approx(1.0, abs=0.03)


def test_uniform_cos_bank() -> None:
    angles = bank_angles(CFG, "uniform_cos")
    np.testing.assert_allclose(np.cos(angles), 1 - 2 * np.arange(30) / 29, atol=1e-12)
    hm = heatmap_of_run(wall_run(2.0, 40.0), 1, bank="uniform_cos")
    peak = find_peak(hm)
    local_half_bin = np.degrees(np.diff(angles)).max() / 2
    assert abs(math.degrees(peak.angle_rad) - 40.0) <= local_half_bin


# ---- angular resolution vs M (paper Fig. 7) -------------------------------------------------
def minus3db_width_deg(hm: HeatMap) -> float:
    """-3 dB width in degrees of the angle profile through the peak, crossings interpolated."""
    peak = find_peak(hm)
    col = hm.H[:, peak.n_tau] / hm.H[peak.n_theta, peak.n_tau]
    deg = np.degrees(hm.angles_rad)
    level = 1 / math.sqrt(2)
    i = peak.n_theta
    while i > 0 and col[i - 1] >= level:
        i -= 1
    lo = deg[0] if i == 0 else np.interp(level, [col[i - 1], col[i]], [deg[i - 1], deg[i]])
    j = peak.n_theta
    while j < col.size - 1 and col[j + 1] >= level:
        j += 1
    hi = deg[-1] if j == col.size - 1 else np.interp(level, [col[j + 1], col[j]],
                                                      [deg[j + 1], deg[j]])
    return float(hi - lo)


def test_angular_width_shrinks_with_m(record_property: Callable[[str, object], None]) -> None:
    widths = {}
    for m in (4, 6, 8, 10):
        hm = heatmap_of_run(wall_run(2.0, 60.0, V, m), 1, bank="uniform_cos")
        widths[m] = minus3db_width_deg(hm)
    print("\n-3 dB angular width at 60 deg, 0.1 m/s (deg):",
          {m: round(w, 2) for m, w in widths.items()})
    record_property("minus3db_width_deg", widths)
    w = [widths[m] for m in (4, 6, 8, 10)]
    assert all(a > b for a, b in zip(w, w[1:], strict=False)), w
    # Doppler resolution ~ c / (2 v T sin theta): the width scales roughly as 1/M
    assert w[0] / w[3] == pytest.approx(10 / 4, rel=0.35)


# ---- speed 0, reversing, wrap ---------------------------------------------------------------
def test_speed_zero_all_rows_equal_and_flagged() -> None:
    run = wall_run(2.0, 50.0, 0.0)
    hm = heatmap_of_run(run, 1)
    assert not hm.direction_observable
    np.testing.assert_array_equal(hm.H, np.broadcast_to(hm.H[0], hm.H.shape))
    assert find_peak(hm).range_m == pytest.approx(2.0, abs=RANGE_SAMPLE_M)
    slow = doppler_heatmap(run.block(1), 0.002, CFG)
    assert not slow.direction_observable
    assert heatmap_of_run(wall_run(2.0, 50.0), 1).direction_observable


def test_negative_speed_means_angles_from_the_backward_travel_direction() -> None:
    block = wall_run(2.0, 40.0).block(1)
    fwd = doppler_heatmap(block, V, CFG)
    rev = doppler_heatmap(block, -V, CFG)
    np.testing.assert_array_equal(fwd.H, rev.H)
    assert rev.speed_m_s == -V
    # eq. 1 with signed v and angles from the body heading = rows reversed
    signed = doppler_ratios(-V, bank_angles(CFG), CFG.sound_speed_m_s)
    np.testing.assert_allclose(signed[::-1], doppler_ratios(V, bank_angles(CFG), 340.0))


def test_echo_beyond_max_range_wraps() -> None:
    # documented: an echo at R appears at R mod c L Tc / 2 = R mod 17.39 m (18 m -> 0.61 m)
    run = wall_run(18.0, 60.0)
    truth = run_truth(run, 1)
    peak = find_peak(heatmap_of_run(run, 1))
    assert CFG.max_range_m == pytest.approx(17.391, abs=1e-3)
    assert truth.range_m % CFG.max_range_m == pytest.approx(0.61, abs=0.01)
    assert abs(peak.range_m - truth.range_m % CFG.max_range_m) <= RANGE_SAMPLE_M


# ---- against the exactly resampled echo -----------------------------------------------------
def exact_reference(run: Run, k: int) -> np.ndarray:
    """Eq. 1 with the resampled block evaluated from geometry at the stretched times."""
    cfg = run.config
    b, p, fs = cfg.block_samples, cfg.period_samples, cfg.fs_hz
    alphas = doppler_ratios(float(run.speed_m_s[k]), cfg.angles_rad, cfg.sound_speed_m_s)
    s = tx_period(cfg)
    rows = []
    for a in alphas:
        t = (k * b + b / 2 + a * (np.arange(b) - b / 2)) / fs
        r = echo_samples(t, cfg, run_motion(run), run_target(run), spreading=False)
        folded = r.reshape(cfg.repetitions, p).sum(axis=0)
        h = np.fft.irfft(np.fft.rfft(folded) * np.conj(np.fft.rfft(s)), n=p)
        rows.append(np.abs(hilbert(h)) / (cfg.repetitions * np.dot(s, s)))
    return np.array(rows)


@pytest.fixture(scope="module")
def oblique_run() -> Run:
    return synthetic_run(CFG, Wall(2.0, math.radians(35.0)), V, n_blocks=3, spreading=False)


@pytest.fixture(scope="module")
def oblique_exact(oblique_run: Run) -> np.ndarray:
    return exact_reference(oblique_run, 1)


def test_spectral_method_matches_exact_resampling(
    oblique_run: Run, oblique_exact: np.ndarray, record_property: Callable[[str, object], None]
) -> None:
    hm = heatmap_of_run(oblique_run, 1)
    err = np.max(np.abs(hm.H - oblique_exact)) / oblique_exact.max()
    print(f"\nspectral (8 taps) vs exact resampling: max error {err:.2e} of the peak")
    record_property("spectral_vs_exact", err)
    assert err < 2e-4


def test_direct_windowed_sinc_vs_exact_and_linear_loses_3db(
    oblique_run: Run, oblique_exact: np.ndarray
) -> None:
    sinc16 = heatmap_of_run(oblique_run, 1, method="direct", taps=16).H
    assert np.max(np.abs(sinc16 - oblique_exact)) / oblique_exact.max() < 0.01
    linear = heatmap_of_run(oblique_run, 1, method="direct", taps=2).H
    loss_db = 20 * math.log10(oblique_exact.max() / linear.max())
    print(f"\nlinear interpolation loses {loss_db:.2f} dB at the peak")
    assert loss_db > 1.5


def test_neighbour_samples_are_used(oblique_run: Run, oblique_exact: np.ndarray) -> None:
    with_nb = heatmap_of_run(oblique_run, 1).H
    bare = doppler_heatmap(oblique_run.block(1), V, CFG).H  # reads beyond the block = 0
    err_nb = np.max(np.abs(with_nb - oblique_exact))
    err_bare = np.max(np.abs(bare - oblique_exact))
    assert err_nb < err_bare
    # at a run end the missing ~12 samples cost < 0.1 % of the peak
    assert err_bare < 1e-3 * oblique_exact.max()


def test_windowed_sinc_interpolator_against_band_limited_signal() -> None:
    # exact reference: the band-limited transmitted signal at the stretched times
    n, alpha, left = 4000, float(doppler_ratios(V, np.array([0.3]), 340.0)[0]), 100
    x = transmitted_at(np.arange(-left, n + left) / CFG.fs_hz, CFG)
    exact = transmitted_at((n / 2 + alpha * (np.arange(n) - n / 2)) / CFG.fs_hz, CFG)
    rms = {}
    for taps in (2, 16, 32):
        y = resample_about_centre(x, alpha, n, left=left, taps=taps)
        rms[taps] = float(np.sqrt(np.mean((y - exact) ** 2) / np.mean(exact**2)))
    assert rms[32] < 0.015 and rms[16] < 0.03 and rms[2] > 0.2


# ---- numba kernels vs their numpy twins (tests/mapping/heatmap/naive.py) ---------------------
def _bank_inputs(speed: float, left: int | None, seed: int) -> tuple[np.ndarray, int, np.ndarray]:
    """Zero-padded random samples around a Table 1 block (``left`` neighbour samples before
    it, None = the full margin; 3 fewer than the margin after it, zeros beyond: the reads of
    a run end), the index of block sample 0, and the Doppler ratios of the bank at |speed|."""
    rng = np.random.default_rng(seed)
    margin = required_margin(CFG, speed)
    lo = margin if left is None else left
    x = rng.standard_normal(lo + CFG.block_samples + margin - 3)
    ext = np.zeros(margin + 1 + CFG.block_samples + margin + 1)
    origin = margin + 1
    ext[origin - lo : origin - lo + x.size] = x
    alphas = doppler_ratios(abs(speed), bank_angles(CFG), CFG.sound_speed_m_s)
    return ext, origin, (np.array([1.0]) if speed == 0.0 else alphas)


@pytest.mark.parametrize("left", [None, 0])
@pytest.mark.parametrize("taps", [2, 16])
@pytest.mark.parametrize("speed", [0.1, -0.25, 0.0, 1.7])
def test_resample_fold_kernel_matches_numpy_twin(speed: float, taps: int,
                                                 left: int | None) -> None:
    ext, origin, alphas = _bank_inputs(speed, left, 7)
    p, m = CFG.period_samples, CFG.repetitions
    table = polyphase_table(taps)
    fast = np.empty((alphas.size, p))
    _resample_fold(ext, float(origin), CFG.block_samples / 2.0, alphas, m, p, table, fast)
    twin = naive.resample_fold_numpy(ext, float(origin), CFG.block_samples / 2.0, alphas, m, p,
                                     table)
    np.testing.assert_allclose(fast, twin, rtol=0, atol=1e-5 * np.abs(twin).max())
    assert np.max(np.abs(fast - twin)) <= 1e-5 * np.max(np.abs(twin))


@pytest.mark.parametrize("left", [None, 0, "unpadded"])
@pytest.mark.parametrize("taps", [2, 8])
@pytest.mark.parametrize("speed", [0.1, -0.25, 0.0, 1.7])
def test_spectral_bank_kernel_matches_numpy_twin(speed: float, taps: int,
                                                 left: int | str | None) -> None:
    """Random spectrum, gridding table, samples and filter: the kernel (window-edge strips
    reading zeros beyond the samples or outside the array, none at alpha = 1) against the
    twin."""
    import scipy.fft

    rng = np.random.default_rng(11)
    unpadded = left == "unpadded"
    ext, origin, alphas = _bank_inputs(speed, None if left is None else 0, 8)
    if unpadded:  # strips read before index 0 and past the end of ext
        ext, origin = np.ascontiguousarray(ext[origin : origin + CFG.block_samples]), 0
    b, p = CFG.block_samples, CFG.period_samples
    nf = scipy.fft.next_fast_len(2 * b, real=True)
    nf += nf % 2
    spec = np.fft.rfft(rng.standard_normal(nf))
    per_unit = 2048
    table = rng.random((per_unit + 1, taps))
    conj_tx = rng.standard_normal(p // 2 + 1) + 1j * rng.standard_normal(p // 2 + 1)
    pad = taps + 2 + int(math.ceil(nf / 2.0 * (1.0 / float(alphas.min()) - 1.0)))
    spec_re, spec_im = naive.hermitian_extended(spec, pad)
    grid = _SpectralGrid(spec_re, spec_im, pad, nf, taps, table, per_unit)
    window = _Window(ext, origin, b, b / 2.0, b // 2, STRIP_STEP_RAD)
    fast = np.empty((alphas.size, p), dtype=np.complex64)
    _spectral_bank(grid, window, alphas, p, conj_tx, fast)
    twin = naive.spectral_bank_numpy(spec, nf, ext, origin, b, b / 2.0, b // 2, alphas, p,
                                     taps, table, per_unit, conj_tx)
    np.testing.assert_allclose(fast, twin, rtol=0, atol=1e-5 * np.abs(twin).max())
    assert np.max(np.abs(fast - twin)) <= 1e-5 * np.max(np.abs(twin))


def test_hermitian_extension_is_the_full_dft() -> None:
    x = np.random.default_rng(5).standard_normal(64)
    re, im = naive.hermitian_extended(np.fft.rfft(x), 10)
    full = np.fft.fft(x)
    np.testing.assert_allclose(re + 1j * im, full[np.arange(-10, 33 + 10) % 64], atol=1e-12)


@settings(max_examples=15, deadline=None)
@given(
    speed=st.floats(-30.0, 30.0, allow_nan=False),
    left=st.integers(0, 40),
    right=st.integers(0, 40),
    bank=st.sampled_from(["uniform_angle", "uniform_cos"]),
    seed=st.integers(0, 2**32 - 1),
)
def test_shapes_and_invariants(speed: float, left: int, right: int, bank: str,
                               seed: int) -> None:
    x = np.random.default_rng(seed).standard_normal(left + SMALL.block_samples + right)
    hm = doppler_heatmap(x, speed, SMALL, left=left, right=right, bank=bank)  # type: ignore[arg-type]
    n_dirs, p = SMALL.directions + 1, SMALL.period_samples
    assert hm.H.shape == (n_dirs, p) and hm.H.dtype == np.float64
    assert np.all(np.isfinite(hm.H)) and np.all(hm.H >= 0)
    assert hm.angles_rad.shape == (n_dirs,) and np.all(np.diff(hm.angles_rad) > 0)
    assert hm.angles_rad[0] == 0.0 and hm.angles_rad[-1] == pytest.approx(math.pi)
    np.testing.assert_allclose(hm.ranges_m, np.arange(p) * SMALL.range_per_sample_m)
    # linearity: scaling the input scales the map (last FFT in single precision)
    scaled = doppler_heatmap(3 * x, speed, SMALL, left=left, right=right, bank=bank)  # type: ignore[arg-type]
    assert np.max(np.abs(scaled.H - 3 * hm.H)) <= 1e-5 * 3 * hm.H.max()


# ---- bad input --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(block=np.zeros(100)), "block must have"),
        (dict(block=np.zeros((2, CFG.block_samples))), "1-D"),
        (dict(block=np.r_[np.nan, np.zeros(CFG.block_samples - 1)]), "NaN or inf"),
        (dict(block=np.r_[np.inf, np.zeros(CFG.block_samples - 1)]), "NaN or inf"),
        (dict(speed_m_s=float("nan")), "speed_m_s"),
        (dict(speed_m_s=float("inf")), "speed_m_s"),
        (dict(speed_m_s=34.0), "speed_m_s"),
        (dict(speed_m_s=-40.0), "speed_m_s"),
        (dict(taps=7), "taps"),
        (dict(bank="random"), "bank"),
        (dict(method="magic"), "method"),
        (dict(left=-1), "left"),
        (dict(config="table1"), "config"),
    ],
)
def test_bad_input_raises_value_error_naming_it(kwargs: dict, match: str) -> None:
    args = dict(block=np.zeros(CFG.block_samples), speed_m_s=V, config=CFG)
    args.update(kwargs)
    block, speed, config = args.pop("block"), args.pop("speed_m_s"), args.pop("config")
    with pytest.raises(ValueError, match=match):
        doppler_heatmap(block, speed, config, **args)  # type: ignore[arg-type]


# ---- CLI edges (omnisonar heatmap / demo) -----------------------------------------------------
def test_cli_heatmap_writes_documented_npz_and_png(tmp_path: object) -> None:
    from pathlib import Path

    from mapping.files import write_run
    from service.cli import main

    tmp = Path(str(tmp_path))
    run = synthetic_run(SMALL, Wall(1.0, math.radians(60.0)), 0.5, n_blocks=2)
    write_run(tmp / "run.npz", run)
    out, png = tmp / "hm.npz", tmp / "hm.png"
    assert main(["heatmap", str(tmp / "run.npz"), "--block", "1", "--out", str(out),
                 "--png", str(png)]) == 0
    with np.load(out) as npz:
        assert set(npz.files) == {"H", "angles_rad", "ranges_m", "speed_m_s",
                                  "direction_observable"}
        np.testing.assert_array_equal(npz["H"], heatmap_of_run(run, 1).H)
        assert bool(npz["direction_observable"]) and float(npz["speed_m_s"]) == 0.5
    assert png.stat().st_size > 0
    assert main(["heatmap", str(tmp / "run.npz"), "--block", "5"]) == 2


def test_cli_demo_prints_range_and_angle_against_truth(
    tmp_path: object, capsys: pytest.CaptureFixture[str]
) -> None:
    from pathlib import Path

    from service.cli import main

    out = Path(str(tmp_path)) / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "detected: range" in text and "truth:" in text
    assert (out / "heatmap.png").stat().st_size > 0
    # part 2, through the API: the map's beta calibrated on a drive, then the held-out run
    import json

    assert "calibration drive" in text and "-> beta" in text
    summary = json.loads((out / "api" / "track.json").read_text())["summary"]
    assert 50.0 <= summary["beta"] <= 400.0
    assert summary["position_rmse_m"] <= 0.05 and summary["share_within_10cm"] == 1.0
    assert 0.0 < summary["nees_mean"] < 30.0
