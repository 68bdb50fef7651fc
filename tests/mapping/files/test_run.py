"""Run file v1: round trip, validation, atomic writes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mapping.files import read_run, write_run
from mapping.run import Run
from mapping.signal import SonarConfig


def _run(n: int = 3) -> Run:
    cfg = SonarConfig(sequence_length=127, repetitions=2)
    rng = np.random.default_rng(1)
    pose = rng.normal(size=(n, 3))
    pose[1] = np.nan
    return Run(
        config=cfg,
        samples=rng.normal(size=(n, cfg.block_samples)).astype(np.float32),
        t_s=np.arange(n, dtype=np.float64) * cfg.block_s,
        speed_m_s=np.full(n, 0.1),
        yaw_rate_rad_s=np.zeros(n),
        pose=pose,
        scene='{"walls": []}',
        meta={"engine": "test"},
    )


def test_round_trip(tmp_path: Path) -> None:
    run = _run()
    path = write_run(tmp_path / "r.npz", run)
    back = read_run(path)
    assert back.config == run.config
    np.testing.assert_array_equal(back.samples, run.samples)
    np.testing.assert_array_equal(back.pose, run.pose)
    assert back.scene == run.scene and back.meta == run.meta
    assert not list(tmp_path.glob("*.tmp"))


def test_truncated_file_is_refused(tmp_path: Path) -> None:
    path = write_run(tmp_path / "r.npz", _run())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="r.npz"):
        read_run(path)


def test_wrong_shapes_name_the_field() -> None:
    run = _run()
    with pytest.raises(ValueError, match="speed_m_s"):
        Run(run.config, run.samples, run.t_s, run.speed_m_s[:2], run.yaw_rate_rad_s, run.pose)
    with pytest.raises(ValueError, match="samples"):
        Run(run.config, run.samples[:, :10], run.t_s, run.speed_m_s, run.yaw_rate_rad_s,
            run.pose)


def test_neighbourhood_uses_adjacent_blocks() -> None:
    run = _run()
    ext, left, right = run.neighbourhood(1, 5)
    assert (left, right) == (5, 5)
    np.testing.assert_array_equal(ext[:5], run.samples[0, -5:])
    ext0, left0, _ = run.neighbourhood(0, 5)
    assert left0 == 0 and ext0.size == run.config.block_samples + 5
