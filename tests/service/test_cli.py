"""Tests of the ``omnisonar`` command line on files: localize and calibrate."""

from __future__ import annotations

import dataclasses
import json
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
    rows = np.loadtxt(tmp_path / "track.csv", delimiter=",", skiprows=1)
    assert rows.shape == (held.n_blocks, 13)
    assert main(["localize", "--map", str(tmp_path / "G.npz"), str(tmp_path / "run.npz"),
                 "--particles", "0"]) == 2


@pytest.mark.slow
def test_cli_calibrate_and_localize_with_beta(simulated: tuple[Any, Any], tmp_path: Any,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """``omnisonar calibrate`` on a tracked run prints the NEES per candidate and the picked
    beta (JSON), ``localize --beta`` uses it; bad input exits 2 naming the problem."""

    from mapping.files import write_map, write_run
    from service.cli import main

    wall_map, held = simulated
    write_map(tmp_path / "G.npz", wall_map)
    write_run(tmp_path / "run.npz", held)
    rc = main(["calibrate", "--map", str(tmp_path / "G.npz"), str(tmp_path / "run.npz"),
               "--betas", "100,200", "--particles", "300", "--seeds", "1", "--json"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["betas"] == [100.0, 200.0] and len(out["nees_mean"]) == 2
    assert 100.0 <= out["beta"] <= 200.0
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
