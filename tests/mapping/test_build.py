"""Batch building: end-to-end single wall, determinism over workers, refusals, dask."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mapping.build import BuildParams, RunSource, build_map, process_pool
from mapping.grid import GridParams
from mapping.reconstruct import InverseParams
from mapping.run import Run
from mapping.signal import SonarConfig
from mapping.synthetic import Wall, synthetic_run

SMALL = SonarConfig(sequence_length=127, repetitions=4)  # B = 2032 samples, range 2.16 m


@pytest.fixture(scope="module")
def wall_run() -> Run:
    return synthetic_run(SonarConfig(), Wall(1.5, 1.2), 0.1, n_blocks=7)


def _small_runs() -> list[Run]:
    runs = []
    for i, (d, a) in enumerate([(1.0, 1.2), (0.8, 2.0), (1.2, 0.7)]):
        r = synthetic_run(SMALL, Wall(d, a), 0.5, n_blocks=4, heading_rad=0.3 * i)
        runs.append(dataclasses.replace(r, pose=r.pose + np.array([0.2 * i, -0.1 * i, 0.0])))
    return runs


def test_single_wall_end_to_end_ridge_and_mirror(wall_run: Run) -> None:
    """Real echoes (synthetic model) -> Doppler heat maps -> G: the ridge lies on the wall
    within one cell and the ghost on the wall's reflection about the path line (y = 0)."""
    wm = build_map([RunSource.from_run(wall_run)], BuildParams(grid=GridParams(radius_m=2.5)))
    assert wm.provenance["blocks_used"] == 7
    n = np.array([np.cos(1.2), np.sin(1.2)])
    ref = wall_run.pose[3, :2]  # the wall is 1.5 m away along n at the reference block
    s = np.linspace(-0.3, 0.3, 61)
    for k in (1, 3, 5):
        p = wall_run.pose[k, :2]
        along = 1.5 - (p - ref) @ n
        for mirror in (np.array([1.0, 1.0]), np.array([1.0, -1.0])):
            nn = n * mirror
            foot = p + along * nn
            pts = foot + s[:, None] * nn
            ij = np.round(wm.world_to_cell(pts)).astype(int)
            peak = s[np.argmax(wm.G[ij[:, 1], ij[:, 0]])]
            assert abs(peak) <= wm.resolution_m


@pytest.mark.slow
def test_bit_identical_whatever_the_workers() -> None:
    """Two spawned worker processes give the same bits as one process (both methods)."""
    runs = _small_runs()
    sources = [RunSource.from_run(r, f"run{i}") for i, r in enumerate(runs)]
    with process_pool(2) as pool:
        for method in ("paper", "inverse"):
            params = BuildParams(method=method, grid=GridParams(radius_m=1.5),
                                 inverse=InverseParams(iterations=20))
            one = build_map(sources, params, workers=1)
            two = build_map(sources, params, executor=pool)
            assert np.array_equal(one.G, two.G)
            assert one.origin_m == two.origin_m
            assert [r["path"] for r in two.provenance["runs"]] == ["run0", "run1", "run2"]


def test_differing_configs_refused_and_untracked_counted() -> None:
    runs = _small_runs()
    other = synthetic_run(SonarConfig(sequence_length=127, repetitions=2), Wall(1.0, 1.0), 0.5,
                          n_blocks=2)
    with pytest.raises(ValueError, match="different sonar configs.*repetitions"):
        build_map([RunSource.from_run(runs[0], "a"), RunSource.from_run(other, "b")])
    pose = runs[0].pose.copy()
    pose[1] = np.nan
    holed = dataclasses.replace(runs[0], pose=pose)
    wm = build_map([RunSource.from_run(holed)], BuildParams(grid=GridParams(radius_m=1.5)))
    assert wm.provenance["blocks_untracked"] == 1 and wm.provenance["blocks_used"] == 3
    blind = dataclasses.replace(runs[0], pose=np.full_like(pose, np.nan))
    with pytest.raises(ValueError, match="nothing to map"):
        build_map([RunSource.from_run(blind)])
    with pytest.raises(ValueError, match="workers"):
        build_map([RunSource.from_run(holed)], workers=0)
    with pytest.raises(ValueError, match="method"):
        BuildParams(method="magic")


def test_dask_local_cluster_matches_processes() -> None:
    distributed = pytest.importorskip("distributed")
    runs = _small_runs()
    params = BuildParams(grid=GridParams(radius_m=1.5))
    sources = [RunSource.from_run(r, f"run{i}") for i, r in enumerate(runs)]
    ref = build_map(sources, params, workers=1)
    with distributed.LocalCluster(processes=False, n_workers=2, threads_per_worker=1,
                                  dashboard_address=None) as cluster:
        with distributed.Client(cluster) as client:
            wm = build_map(sources, params, client=client)
    assert np.array_equal(wm.G, ref.G)


def test_cli_build_and_evaluate_map(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    import json

    from mapping.files import read_map, write_run
    from service.cli import main

    runs = _small_runs()
    paths = [write_run(tmp_path / f"r{i}.npz", r) for i, r in enumerate(runs[:2])]
    out = tmp_path / "m.npz"
    code = main(["build-map", *map(str, paths), "--out", str(out), "--method", "paper",
                 "--radius-m", "1.5",
                 "--png", str(tmp_path / "m.png"), "--pgm", str(tmp_path / "m.pgm")])
    assert code == 0
    wm = read_map(out)
    assert wm.method == "paper" and len(wm.provenance["runs"]) == 2
    assert all(len(r["sha256"]) == 64 for r in wm.provenance["runs"])
    assert (tmp_path / "m.png").stat().st_size > 0 and (tmp_path / "m.yaml").exists()
    capsys.readouterr()
    assert main(["evaluate-map", str(out), "--scene", "builtin:shoebox", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    p99 = report["fraction_of_p99"]
    assert 0 <= p99["ghost_energy"] <= 1 and len(p99["at"]) == 3
    other = synthetic_run(SonarConfig(sequence_length=127, repetitions=2), Wall(1.0, 1.0), 0.5,
                          n_blocks=2)
    p3 = write_run(tmp_path / "other.npz", other)
    assert main(["build-map", str(paths[0]), str(p3), "--out", str(out)]) == 2
    assert "different sonar configs" in capsys.readouterr().err
