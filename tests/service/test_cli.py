"""The ``omnisonar`` command line on files: localize, calibrate, build-map, evaluate-map."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from typing import Any

import numpy as np
import pytest


@pytest.mark.slow
def test_cli_localize_tracked(simulated: tuple[Any, Any], tmp_path: Any,
                              capsys: pytest.CaptureFixture[str]) -> None:
    """``omnisonar localize --init tracked --json`` on files: converged from block 0, RMSE
    <= 3 cm, and the CSV track has one row per block."""

    from mapping.files import write_map, write_run
    from service.cli import main

    wall_map, held = simulated
    write_map(tmp_path / "G.npz", wall_map)
    write_run(tmp_path / "run.npz", held)
    rc = main(["localize", "--map", str(tmp_path / "G.npz"), str(tmp_path / "run.npz"),
               "--init", "tracked", "--particles", "1000", "--json",
               "--out", str(tmp_path / "track.csv")])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["blocks_to_converge"] == 0 and out["position_rmse_m"] <= 0.03
    rows = np.loadtxt(tmp_path / "track.csv", delimiter=",", skiprows=1,
                      converters={19: lambda s: 1.0 if s == "converged" else 0.0,
                                  22: lambda s: float(len(s))})      # reason: "" when converged
    assert rows.shape == (held.n_blocks, 23)
    assert np.all((rows[:, 19] == 1.0) == (rows[:, 22] == 0.0))
    assert main(["localize", "--map", str(tmp_path / "G.npz"), str(tmp_path / "run.npz"),
                 "--particles", "0"]) == 2


@pytest.mark.slow
def test_cli_calibrate_and_localize_with_beta(simulated: tuple[Any, Any], tmp_path: Any,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """``omnisonar calibrate`` on a tracked run prints the NEES per candidate and the picked
    beta (JSON), ``localize --beta`` uses it; bad input exits 2 naming the problem.

    On this run 100 and 200 stay below mean NEES 3, so ``calibrate`` warns and widens to 400
    (issue 14 item 4); before widening it silently returned 200, the nearest."""

    from mapping.files import write_map, write_run
    from service.cli import main

    wall_map, held = simulated
    write_map(tmp_path / "G.npz", wall_map)
    write_run(tmp_path / "run.npz", held)
    rc = main(["calibrate", "--map", str(tmp_path / "G.npz"), str(tmp_path / "run.npz"),
               "--betas", "100,200", "--particles", "300", "--seeds", "1", "--json"])
    assert rc == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert out["betas"] == [100.0, 200.0, 400.0] and len(out["nees_mean"]) == 3
    assert out["widened"] == [400.0] and out["bracketed"] is True
    assert 200.0 <= out["beta"] <= 400.0
    assert "no candidate beta brackets" in captured.err and "tried beta 400" in captured.err
    rc = main(["localize", "--map", str(tmp_path / "G.npz"), str(tmp_path / "run.npz"),
               "--init", "tracked", "--particles", "500", "--beta", str(out["beta"]),
               "--json"])
    assert rc == 0 and json.loads(capsys.readouterr().out)["position_rmse_m"] <= 0.03
    assert main(["localize", "--map", str(tmp_path / "G.npz"), str(tmp_path / "run.npz"),
                 "--beta", "-1"]) == 2
    assert "beta" in capsys.readouterr().err
    assert main(["calibrate", "--map", str(tmp_path / "G.npz"), str(tmp_path / "run.npz"),
                 "--betas", "a,b"]) == 2
    assert "--betas" in capsys.readouterr().err
    untracked = dataclasses.replace(held, pose=np.full_like(held.pose, np.nan))
    write_run(tmp_path / "untracked.npz", untracked)
    assert main(["calibrate", "--map", str(tmp_path / "G.npz"),
                 str(tmp_path / "untracked.npz")]) == 2
    assert "untracked.npz" in capsys.readouterr().err


def test_cli_calibrate_warns_and_widens_when_no_candidate_brackets(
        tmp_path: Any, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 14 item 4: with a fake filter whose mean NEES is 3 beta / 5000 (the real search
    of ``localization.calibration`` over it), the default candidates 50..400 never reach 3:
    ``calibrate`` warns on stderr naming what it tried, doubles up to 6400 and picks the
    crossing 5000; ``--widen 2`` stops at 1600 and says it picked the nearest, unbracketed;
    a bracketing range warns nothing; ``--widen -1`` exits 2."""
    import localization.calibration as calibration
    from mapping.files import write_map, write_run
    from service.cli import main
    from tests.service.helpers import raster_map

    def fake_calibrate(tables: Any, runs: Any, betas: Any, config: Any, rng: Any,
                       n_seeds: int = 1, max_widen: int = 0) -> Any:
        assert len(runs) == 1 and n_seeds == 1
        return calibration.search_beta(lambda b: (3.0 * b / 5000.0, 0), betas,
                                       max_widen=max_widen)

    monkeypatch.setattr(calibration, "calibrate_beta", fake_calibrate)
    map_path = write_map(tmp_path / "G.npz", raster_map())
    run_path = write_run(tmp_path / "run.npz", _small_run(None))
    base = ["calibrate", "--map", str(map_path), str(run_path), "--seeds", "1"]

    assert main([*base, "--json"]) == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert out["widened"] == [800.0, 1600.0, 3200.0, 6400.0] and out["bracketed"] is True
    assert out["betas"] == [50.0, 100.0, 200.0, 400.0, 800.0, 1600.0, 3200.0, 6400.0]
    assert out["beta"] == pytest.approx(5000.0)
    err = " ".join(captured.err.split())
    assert "warning: no candidate beta brackets the target mean NEES 3" in err
    assert "50: 0.03" in err and "400: 0.24" in err        # the given candidates' NEES
    assert "tried beta 800: 0.48, 1600: 0.96, 3200: 1.92, 6400: 3.84" in err
    assert "crossing lies at beta 5000.0" in err

    assert main([*base, "--widen", "2"]) == 0
    captured = capsys.readouterr()
    err = " ".join(captured.err.split())
    assert "tried beta 800: 0.48, 1600: 0.96" in err and "3200" not in err
    assert "stopped at the cap of 2" in err and "Picked the nearest, beta = 1600.0" in err
    assert " 1600.0 " in captured.out and "the nearest candidate" in captured.out

    assert main([*base, "--widen", "0"]) == 0
    assert "--widen 0 turns widening off" in capsys.readouterr().err

    assert main([*base, "--betas", "1000,10000"]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and "mean NEES 3 = honest covariance" in captured.out

    assert main([*base, "--widen", "-1"]) == 2
    assert "--widen" in capsys.readouterr().err


# ---- localize: strict JSON, RMSE over all blocks, the track CSV (issue 14 item 4) ---------
def _reject_constant(name: str) -> Any:
    raise ValueError(f"not strict JSON: {name}")


def test_localize_never_converged_prints_strict_json_and_full_track_csv(
        tmp_path: Any, capsys: pytest.CaptureFixture[str]) -> None:
    """Regression: a run that never converges printed ``NaN`` in ``--json`` (invalid JSON).
    The run's truth lies 100 m from the map, so no block is ever within 10 cm: the fields
    after convergence are null, the RMSE over all blocks is a number (~141 m). The track CSV
    carries the full covariance and a status per block; the text says "never converged"."""
    from mapping.files import write_map, write_run
    from service.cli import main
    from tests.service.helpers import raster_map

    run = _small_run(None)
    far = dataclasses.replace(run, pose=run.pose + np.array([100.0, 100.0, 0.0]))
    map_path = write_map(tmp_path / "G.npz", raster_map())
    run_path = write_run(tmp_path / "far.npz", far)
    csv_path = tmp_path / "out" / "track.csv"
    base = ["localize", "--map", str(map_path), str(run_path), "--particles", "300"]
    assert main([*base, "--json", "--out", str(csv_path)]) == 0
    out = json.loads(capsys.readouterr().out, parse_constant=_reject_constant)
    assert out["blocks_to_converge"] is None
    for key in ("position_rmse_m", "heading_rmse_rad", "heading_rmse_deg", "nees_mean"):
        assert out[key] is None, key
    assert out["position_rmse_all_m"] == pytest.approx(100.0 * math.sqrt(2.0), abs=5.0)
    assert math.isfinite(out["heading_rmse_all_rad"]) and math.isfinite(
        out["heading_rmse_all_deg"])

    lines = csv_path.read_text().splitlines()
    assert lines[0] == ("block,x_m,y_m,yaw_rad,std_x_m,std_y_m,std_yaw_rad,ess,converged,"
                        "n_modes,direction_observable,err_m,err_rad,cov_xx,cov_xy,cov_xyaw,"
                        "cov_yy,cov_yyaw,cov_yawyaw,status,refined,reckoned,reason")
    assert len(lines) == 1 + far.n_blocks and not list(tmp_path.joinpath("out").glob(".*"))
    header = lines[0].split(",")
    for line in lines[1:]:
        row = dict(zip(header, line.split(","), strict=True))
        cov = np.array([[row["cov_xx"], row["cov_xy"], row["cov_xyaw"]],
                        [row["cov_xy"], row["cov_yy"], row["cov_yyaw"]],
                        [row["cov_xyaw"], row["cov_yyaw"], row["cov_yawyaw"]]], dtype=float)
        np.testing.assert_allclose(np.sqrt(np.diag(cov)),
                                   [float(row["std_x_m"]), float(row["std_y_m"]),
                                    float(row["std_yaw_rad"])], rtol=1e-4)
        assert np.linalg.eigvalsh(cov).min() >= -1e-12
        # the G model has no misfit count (never lost); a converged set is reported
        # converged only once a global start is confirmed (FilterConfig.confirm_blocks)
        assert row["status"] in ("converged", "uncertain")
        assert row["converged"] == "1" or row["status"] == "uncertain"
        assert float(row["err_m"]) > 100.0

    assert main(base) == 0
    text = capsys.readouterr().out
    assert "never converged" in text and "over all blocks position RMSE" in text
    assert "nan" not in text.splitlines()[-1]


def test_strict_json_nulls_every_non_finite_float() -> None:
    from service.jsonout import strict_json

    value = {"a": math.nan, "b": [1.0, math.inf, (np.float64(-math.inf), np.int64(3))],
             "c": {"d": np.array([np.nan, 2.0]), "e": np.bool_(True), "f": None, "g": "NaN"}}
    assert json.loads(strict_json(value), parse_constant=_reject_constant) == {
        "a": None, "b": [1.0, None, [None, 3]],
        "c": {"d": [None, 2.0], "e": True, "f": None, "g": "NaN"}}


# ---- build-map / evaluate-map (issue 13) ------------------------------------------------------
def _small_run(scene: str | None) -> Any:
    from mapping.signal import SonarConfig
    from mapping.synthetic import Wall, synthetic_run

    run = synthetic_run(SonarConfig(sequence_length=127, repetitions=4), Wall(1.0, 1.2), 0.5,
                        n_blocks=4)
    return dataclasses.replace(run, scene=scene)


def test_build_map_png_with_unparsable_scene_warns_and_succeeds(
        tmp_path: Any, capsys: pytest.CaptureFixture[str]) -> None:
    """Regression: the map was written, then the PNG's scene overlay raised and the command
    exited 2. Now: a warning on stderr, a PNG without true walls, exit 0; the other outputs
    (PGM/YAML, GeoJSON) are written too."""
    from mapping.files import read_map, write_run
    from service.cli import main

    run_path = write_run(tmp_path / "r.npz", _small_run('{"name": "broken", "walls": [1, 2]'))
    out = tmp_path / "m.npz"
    rc = main(["build-map", str(run_path), "--method", "paper", "--out", str(out),
               "--radius-m", "1.5", "--png", str(tmp_path / "m.png"),
               "--pgm", str(tmp_path / "m.pgm"), "--geojson", str(tmp_path / "m.geojson")])
    captured = capsys.readouterr()
    assert rc == 0
    assert "warning" in captured.err and "r.npz" in captured.err and "scene" in captured.err
    assert (tmp_path / "m.png").stat().st_size > 0 and (tmp_path / "m.yaml").exists()
    assert read_map(out).method == "paper"
    assert json.loads((tmp_path / "m.geojson").read_text())["features"] == []


def _scene_map(tmp_path: Any) -> tuple[Any, Any]:
    """A map whose fitted walls are the shoebox's walls plus one ghost, and G drawn on them."""
    from mapping.files import write_map
    from mapping.scene import builtin_scene
    from mapping.wallmap import WallMap, rasterize_walls

    seg = builtin_scene("shoebox").segments()
    walls = np.vstack([seg.reshape(-1, 4), [[0.5, -1.0, 2.5, -1.0]]])
    lo, hi = seg.reshape(-1, 2).min(axis=0) - 1.5, seg.reshape(-1, 2).max(axis=0) + 0.5
    x, y = np.arange(lo[0], hi[0], 0.05), np.arange(lo[1], hi[1], 0.05)
    G = rasterize_walls(seg.reshape(-1, 4), x, y).astype(np.float64)
    wm = WallMap(G=G, origin_m=(float(x[0]), float(y[0])), resolution_m=0.05, method="walls",
                 walls_m=walls)
    return write_map(tmp_path / "walls.npz", wm), seg


def test_evaluate_map_reports_wall_level_and_raster(
        tmp_path: Any, capsys: pytest.CaptureFixture[str]) -> None:
    from service.cli import main

    path, seg = _scene_map(tmp_path)
    assert main(["evaluate-map", str(path), "--scene", "builtin:shoebox", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    walls, raster = report["walls"], report["raster"]
    assert walls["recall"] == 1.0 and walls["n_found"] == len(seg)
    assert walls["false_walls"] == [len(seg)] and walls["precision"] == pytest.approx(
        len(seg) / (len(seg) + 1))
    assert walls["angle_error_deg_max"] == pytest.approx(0.0, abs=1e-6)
    assert raster["precision"] == 1.0 and raster["recall"] == 1.0 and raster["fraction"] == 0.2
    assert len(report["fraction_of_p99"]["at"]) == 3 and "ghost_energy" in report[
        "fraction_of_p99"]
    assert main(["evaluate-map", str(path), "--scene", "builtin:shoebox"]) == 0
    text = capsys.readouterr().out
    assert "walls:  precision" in text and "recall 1.000" in text
    assert "x max(G) inside coverage" in text and "fraction_of_p99" in text
    assert main(["evaluate-map", str(path), "--scene", "builtin:shoebox",
                 "--p99-fractions", "a"]) == 2
    assert "--p99-fractions" in capsys.readouterr().err


def test_build_and_evaluate_map_help_show_defaults() -> None:
    from service.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    build, evaluate = sub.choices["build-map"], sub.choices["evaluate-map"]
    assert "(default: walls)" in " ".join(build.format_help().split())
    assert "(default: 0.05)" in " ".join(build.format_help().split())
    help_eval = " ".join(evaluate.format_help().split())
    assert "(default: 0.2)" in help_eval and "(default: 0.8)" in help_eval
    args = parser.parse_args(["build-map", "r.npz", "--out", "m.npz"])
    assert args.method == "walls" and args.geojson is None


def test_every_subcommand_help_shows_its_defaults() -> None:
    """Issue 14 item 4: every option of every subcommand whose default is set (not None, not
    SUPPRESS, not False) says so in its rendered help, and says it once."""
    from service.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing, twice = [], []
    for name, subparser in sub.choices.items():
        formatter = subparser._get_formatter()
        for action in subparser._actions:
            unset = action.default is None or action.default is False  # not 0 == False
            if unset or action.default == argparse.SUPPRESS or not action.option_strings:
                continue
            shown = formatter._expand_help(action) if action.help else ""
            if "default" not in shown:
                missing.append(f"{name} {action.option_strings[0]}")
            elif shown.count("default") > 1:
                twice.append(f"{name} {action.option_strings[0]}: {shown}")
    assert missing == [] and twice == []
    text = " ".join(sub.choices["localize"].format_help().split())
    assert "(default: global)" in text and "(default: 2000)" in text


def test_localize_open_map_choices(capsys: pytest.CaptureFixture[str]) -> None:
    """``localize --open-map``: a choice of the filter's ``open_map_global`` (the help shows
    both and the default); anything else is refused naming the option."""
    from service.cli import main

    with pytest.raises(SystemExit):
        main(["localize", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--open-map {uncertain,confirm}" in text and "uncertain" in text
    with pytest.raises(SystemExit) as exc:
        main(["localize", "--map", "m.npz", "r.npz", "--open-map", "never"])
    assert exc.value.code == 2 and "--open-map" in capsys.readouterr().err
