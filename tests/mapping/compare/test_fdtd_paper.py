"""FDTD reference against the image-source engine on the paper scene (issue 4, last "Must show").

Scene ``builtin:paper``, path ``paper-a``, the block whose midpoint is nearest the paper's
point (a) = (2, 2): sonar at (1.934, 1.934) heading 45 deg. A short window, scaled so both
engines run in seconds: carrier = chip rate = 2.5 kHz, fs = 10 kHz, L = 127, M = 2 periods
(block 0.1016 s) at 2 m/s (Doppler drift 12 samples, as the benchmark's scaled case; the
sonar moves 0.2 m per block, as the paper's 0.1 m per 1.023 s block times two), FDTD warm-up
0.04 s (so both engines hear the paths up to 13.6 m: every echo of the 5 m heat-map window
from the block's first sample on).

Truths, independent of the engines:

- The geometric image-source paths (``mapping.simulate.fdtd_compare``: brute-force wall
  sequences, mirror images, retarded lengths): the image-source path table must equal them,
  and the FDTD's heat-map peaks must sit where they predict (after the grid's group delay).
- The free wall end of Wall 3 at (2.3, 1.36): its diffracted paths (Keller) predict where
  the FDTD hears energy that the image-source engine has no path for.

1 cm grid (13.6 points per wavelength at the carrier): global peaks and the K = 5 strongest
echoes agree within one range bin (17 mm) and one angle bin (6.2 deg). 2 cm grid (6.8 points
per wavelength at the carrier, the paper's own ratio on Table 2's 5 mm grid): the set-up warns,
and the echoes disagree by several range bins even after the dispersion correction (the
documented edge of the method).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pytest

from mapping.compare import (
    BlockComparison,
    compare_block,
    comparison_heatmaps,
    correlation,
    edge_diffraction_paths,
    edge_echo_range_m,
    fdtd_length_m,
    image_point,
    local_maxima,
    specular_path,
    valid_wall_sequences,
    window_peak,
)
from mapping.heatmap import HeatMap, find_peak
from mapping.path import builtin_path
from mapping.scene import Scene, Wall, builtin_scene
from mapping.signal import SonarConfig
from mapping.simulate.fdtd import FdtdConfig

SONAR = SonarConfig(sequence_length=127, carrier_hz=2500.0, chip_rate_hz=2500.0, fs_hz=10_000.0,
                    repetitions=2)
SPEED_M_S = 2.0
WARMUP_S = 0.04
COURANT = 0.566667
#: strongest echoes compared (the sixth local maximum of both maps is a Doppler sidelobe)
K = 5
RMAX_M = 5.0
WALL3_FREE_END = (2.3, 1.36)


@dataclass(frozen=True)
class Case:
    cmp: BlockComparison
    maps: dict[str, HeatMap]
    warned: tuple[str, ...]

    @property
    def range_bin_m(self) -> float:
        return float(self.maps["fdtd"].ranges_m[1])

    @property
    def angle_bin_rad(self) -> float:
        return float(self.maps["fdtd"].angles_rad[1])

    @property
    def n_range(self) -> int:
        return int(np.searchsorted(self.maps["fdtd"].ranges_m, RMAX_M))

    def bins(self, range_m: float, angle_rad: float) -> tuple[float, float]:
        """(angle bin, range bin) of a point, fractional."""
        return angle_rad / self.angle_bin_rad, range_m / self.range_bin_m


def _block_index() -> int:
    return int(round(np.hypot(1.0, 1.0) / (SPEED_M_S * SONAR.block_s) - 0.5))


def _paper_scene(wall3_x0_m: float) -> Scene:
    """The paper scene with Wall 3's free end at ``x = wall3_x0_m`` (2.3 m as built in)."""
    scene = builtin_scene("paper")
    if wall3_x0_m == WALL3_FREE_END[0]:
        return scene
    w = scene.walls
    return Scene(name="paper, wall 3 shortened", walls=[
        w[0], w[1], Wall(name="wall 3", start=w[2].start, end=(wall3_x0_m, w[2].end[1]))])


@lru_cache(maxsize=3)
def _case(grid_step_m: float, wall3_x0_m: float = WALL3_FREE_END[0]) -> Case:
    fdtd = FdtdConfig(grid_step_m=grid_step_m, time_step_s=COURANT * grid_step_m / 340.0,
                      warmup_s=WARMUP_S)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cmp = compare_block(_paper_scene(wall3_x0_m),
                            builtin_path("paper-a", speed_m_s=SPEED_M_S),
                            SONAR, fdtd, _block_index())
    return Case(cmp, comparison_heatmaps(cmp),
                tuple(str(w.message) for w in caught if issubclass(w.category, UserWarning)))


def _rounded_bins(case: Case, i: int) -> tuple[int, int]:
    """(angle bin, range bin) where path i of the table should peak in the FDTD map."""
    e = case.cmp.echoes[i]
    assert e is not None
    a, r = case.bins(e.fdtd_range_m, e.heatmap_angle_rad)
    return int(round(a)), int(round(r))


# ---- the truth itself -----------------------------------------------------------------------
def test_path_table_is_the_geometric_image_source_truth() -> None:
    """Every path of the image-source table exists geometrically, with the retarded delay and
    Doppler factor of its mirror image (delays to 0.1 mm, mean cosines to 0.01), and no valid
    specular path up to order 6 within the heat-map window is missing from the table
    (brute force over all wall sequences)."""
    case = _case(0.01)
    cmp = case.cmp
    seg = builtin_scene("paper").segments()
    c = SONAR.sound_speed_m_s
    cos_d = (cmp.paths.doppler_factor - 1) * c / (2 * cmp.speed_m_s)
    for i, walls in enumerate(cmp.paths.walls):
        e = cmp.echoes[i]
        assert e is not None, walls
        # the table lists the walls in the order the sound hits them: for a moving sonar a
        # path and its reverse differ by ~v tau (2.2 cm here), so the geometric echo of the
        # table's own wall sequence must carry the table's delay (labels were once swapped)
        table_range = c * float(cmp.paths.delay_s[i]) / 2
        assert abs(e.range_m - table_range) < 1e-4, (walls, e.range_m, table_range)
        # mean cosine of departure and arrival against the Doppler factor's (D - 1) c / (2 v);
        # D = (c + v cos) / (c - v cos) has a second-order term the heat map's 1 + 2 v cos / c
        # leaves out, v cos / c = 0.6 % of the cosine at 2 m/s
        assert abs(np.cos(e.heatmap_angle_rad) - cos_d[i]) < 0.01, walls
    found = valid_wall_sequences(seg, cmp.position_m, 6, 2 * RMAX_M)
    table = {tuple(w) for w in cmp.paths.walls}
    images = {tuple(np.round(image_point(cmp.position_m, w, seg), 6)) for w in table}
    for w in found:  # a corner path and its reverse share an image: the table keeps one
        assert w in table or tuple(np.round(image_point(cmp.position_m, w, seg), 6)) in images, w
    assert len(found) >= 8


# ---- 1 cm grid: agreement -------------------------------------------------------------------
def test_fdtd_and_image_source_heatmaps_agree_on_the_paper_scene() -> None:
    """1 cm grid, 13.6 points per wavelength at the carrier (6.8 at the signal's band edge, so
    the set-up warns; the heat map's envelope sits at the carrier): after the grid dispersion
    is applied path by path to the image-source block,

    - waveform correlation > 0.85 (measured 0.886; 0.21 raw);
    - global peaks in the same range bin and angle bin (measured: identical cells);
    - each of the K = 5 strongest local maxima of the FDTD map has a local maximum of the
      image-source map within one range bin and one angle bin (measured: 0/0, 0/0, 0/0,
      1/0, 1/1 range/angle bins), and lies within one range bin and one angle bin of the
      geometric prediction of the path it belongs to (nearest path; measured 1/1, 0/1, 1/0,
      0/0, 1/0);
    - echo by echo, the seven strongest paths of the table, each searched at its predicted
      cell in both maps: the two maps' maxima within one bin.
    """
    case = _case(0.01)
    cmp, maps = case.cmp, case.maps
    hf, hi = maps["fdtd"], maps["ism_dispersed"]
    assert cmp.report.points_per_wavelength_signal_edge * 2 == pytest.approx(13.6, abs=0.05)
    assert correlation(cmp.fdtd, cmp.ism_dispersed) > 0.85
    assert abs(correlation(cmp.fdtd, cmp.ism)) < 0.5  # the dispersion correction matters

    pf, pi = find_peak(hf), find_peak(hi)
    assert abs(pf.n_tau - pi.n_tau) <= 1 and abs(pf.n_theta - pi.n_theta) <= 1

    n = case.n_range
    top_f = local_maxima(hf.H, K, n)
    top_i = local_maxima(hi.H, 2 * K, n)
    assert top_f[0][:2] == (pf.n_theta, pf.n_tau)
    predicted = {i: _rounded_bins(case, i) for i in range(cmp.paths.n)}
    for a, j, _ in top_f:
        assert any(abs(a - b) <= 1 and abs(j - k) <= 1 for b, k, _ in top_i), (a, j, top_i)
        # the path it belongs to: nearest prediction in bin units
        i = min(predicted, key=lambda q: (predicted[q][0] - a) ** 2 + (predicted[q][1] - j) ** 2)
        pa, pr = predicted[i]
        assert abs(a - pa) <= 1 and abs(j - pr) <= 1, (cmp.paths.walls[i], (a, j), (pa, pr))

    half_tau = int(0.15 / case.range_bin_m)
    for i in np.argsort(-cmp.paths.amplitude)[:7]:
        a0, j0 = predicted[int(i)]
        fa, fj, _ = window_peak(hf.H, a0, j0, 2, half_tau)
        ia, ij, _ = window_peak(hi.H, a0, j0, 2, half_tau)
        assert abs(fa - ia) <= 1 and abs(fj - ij) <= 1, (cmp.paths.walls[i], (fa, fj), (ia, ij))


def test_free_wall_end_diffraction_is_heard_by_the_fdtd_only() -> None:
    """Where they disagree on the 1 cm grid: the heat map of the residual waveform (FDTD minus
    the fitted dispersion-corrected image-source block) has a peak of >= 0.15 of the FDTD map's
    maximum (measured 0.22) within one range bin and one angle bin of a path diffracted at
    Wall 3's free end (2.3, 1.36) after one reflection (sonar -> Wall 1 or 2 -> edge ->
    sonar and reverse: 2.70 / 2.74 m, 74 / 78 deg; 2.75 / 2.79 m in the grid), where no
    specular path of the image-source model lies within 3 range bins and 2 angle bins."""
    case = _case(0.01)
    cmp, maps = case.cmp, case.maps
    hf, hr = maps["fdtd"], maps["residual"]
    seg = builtin_scene("paper").segments()
    edges = [e for e in edge_diffraction_paths(seg, cmp.position_m, cmp.position_m,
                                               cmp.velocity_m_s, max_reflections=1)
             if e.edge_m == WALL3_FREE_END and len(e.walls_in) + len(e.walls_out) == 1]
    assert {e.walls_in + e.walls_out for e in edges} == {(0,), (1,)}
    c = SONAR.sound_speed_m_s
    pred = [case.bins(fdtd_length_m(e.points_m, SONAR.carrier_hz, cmp.fdtd_config, c) / 2,
                      e.heatmap_angle_rad) for e in edges]
    peaks = local_maxima(hr.H, 10, case.n_range)
    near = [(a, j, v) for a, j, v in peaks
            if any(abs(a - pa) <= 1 and abs(j - pr) <= 1 for pa, pr in pred)]
    assert near, (peaks, pred)
    a, j, v = max(near, key=lambda p: p[2])
    assert v >= 0.15 * hf.H.max()
    spec = [_rounded_bins(case, i) for i in range(cmp.paths.n)]
    assert all(abs(a - sa) > 2 or abs(j - sr) > 3 for sa, sr in spec), (a, j, spec)
    # the geometric specular path this diffraction replaces: Wall 1 -> Wall 3, whose point
    # on Wall 3 lies 0.37 m beyond the free end (invalid, so not in the table)
    assert specular_path(cmp.position_m, cmp.position_m, (0, 2), seg) is None


@pytest.mark.slow  # two 1 cm FDTD runs (one shared with the tests above): 3 s idle, ~20 s loaded
def test_residual_peaks_sit_on_the_free_end_diffraction_paths_and_move_with_the_end() -> None:
    """Control for the attribution above: on the paper scene and on a copy with Wall 3's free
    end moved to x = 2.1 m, each family of paths diffracted at that end -- direct (sonar ->
    edge -> sonar), via Wall 1, via Wall 2, via Walls 3-2-1 (each with its reverse) -- has a
    peak of the residual map (local maximum >= 0.08 of the FDTD map's maximum) within one
    range bin and one angle bin of its predicted cell (retarded geometry, grid group delay),
    and every family's predicted cell moves by more than one bin between the two scenes, so
    the match follows the edge. Measured (x = 2.3 / 2.1): direct 0.12 / 0.17, via Wall 1
    0.22 / 0.16, via Wall 2 0.22 / 0.10, via Walls 3-2-1 0.32 / 0.37."""
    families = {(): "direct", (0,): "via wall 1", (1,): "via wall 2", (0, 1, 2): "via 3-2-1"}

    def predictions(x0: float) -> dict[tuple[int, ...], list[tuple[float, float]]]:
        case = _case(0.01, x0)
        cmp = case.cmp
        seg = _paper_scene(x0).segments()
        traj = builtin_path("paper-a", speed_m_s=SPEED_M_S)
        t_mid = (cmp.block_index + 0.5) * SONAR.block_s

        def position_at(t: float) -> np.ndarray:
            return np.asarray(traj.position(np.array([t]))[0], dtype=np.float64)

        out: dict[tuple[int, ...], list[tuple[float, float]]] = {f: [] for f in families}
        for e in edge_diffraction_paths(seg, cmp.position_m, cmp.position_m, cmp.velocity_m_s,
                                        max_reflections=3):
            key = tuple(sorted(e.walls_in + e.walls_out))
            if e.edge_m != (x0, WALL3_FREE_END[1]) or key not in out:
                continue
            r = edge_echo_range_m(seg, e, position_at, t_mid, SONAR, cmp.fdtd_config)
            assert r is not None
            out[key].append(case.bins(r[1], e.heatmap_angle_rad))
        return out

    pred = {x0: predictions(x0) for x0 in (2.3, 2.1)}
    for x0, other in ((2.3, 2.1), (2.1, 2.3)):
        case = _case(0.01, x0)
        hf, hr = case.maps["fdtd"], case.maps["residual"]
        peaks = [(a, j) for a, j, v in local_maxima(hr.H, 300, case.n_range)
                 if v >= 0.08 * hf.H.max()]
        for fam, name in families.items():
            # the path and its reverse (the direct path is its own reverse)
            assert len(pred[x0][fam]) == (1 if fam == () else 2), (name, pred[x0][fam])
            hits = [(a, j) for a, j in peaks
                    if any(abs(a - pa) <= 1 and abs(j - pr) <= 1 for pa, pr in pred[x0][fam])]
            assert hits, (x0, name, pred[x0][fam])
            moved = min(max(abs(pa - qa), abs(pr - qr)) for pa, pr in pred[x0][fam]
                        for qa, qr in pred[other][fam])
            assert moved > 1, (name, moved)


# ---- 2 cm grid: the edge of the method ----------------------------------------------------------
def test_under_resolved_grid_disagrees_by_several_range_bins() -> None:
    """DOCUMENTED FAILURE. 2 cm grid: 6.8 points per wavelength at the carrier (the paper's own
    signal on Table 2's 5 mm grid has the same 6.8), 4 at the injected band edge; the set-up
    warns (< 10) and predicts the carrier's envelope 7.9 % slow along the axes. Even with that
    dispersion applied to the image-source block path by path, the echoes are smeared into
    lobes of nearly equal height and the maxima land on different lobes: of the seven
    strongest paths, searched at their predicted cells, at least two differ between the maps by
    >= 3 range bins (measured 8, 7, 3, 2, 1, 1, 1), and the FDTD's own maxima miss the
    predicted cell by >= 3 range bins for at least two of them. The heat maps only agree
    within one bin on the 1 cm grid (test above)."""
    case = _case(0.02)
    cmp, maps = case.cmp, case.maps
    assert any("points per wavelength" in w for w in case.warned), case.warned
    rep = cmp.report
    assert rep.points_per_wavelength_signal_edge * 2 == pytest.approx(6.8, abs=0.05)
    assert rep.points_per_wavelength_injected_edge < 10
    assert rep.group_velocity_error_carrier[0] < -0.07
    hf, hi = maps["fdtd"], maps["ism_dispersed"]
    half_tau = int(0.15 / case.range_bin_m)
    d_maps, d_truth = [], []
    for i in np.argsort(-cmp.paths.amplitude)[:7]:
        a0, j0 = _rounded_bins(case, int(i))
        _, fj, _ = window_peak(hf.H, a0, j0, 2, half_tau)
        _, ij, _ = window_peak(hi.H, a0, j0, 2, half_tau)
        d_maps.append(abs(fj - ij))
        d_truth.append(abs(fj - j0))
    assert sum(d >= 3 for d in d_maps) >= 2, d_maps
    assert sum(d >= 3 for d in d_truth) >= 2, d_truth
    # the 1 cm grid, same echoes, same search: all within one bin
    fine = _case(0.01)
    for i in np.argsort(-fine.cmp.paths.amplitude)[:7]:
        a0, j0 = _rounded_bins(fine, int(i))
        _, fj, _ = window_peak(fine.maps["fdtd"].H, a0, j0, 2, half_tau)
        _, ij, _ = window_peak(fine.maps["ism_dispersed"].H, a0, j0, 2, half_tau)
        assert abs(fj - ij) <= 1
