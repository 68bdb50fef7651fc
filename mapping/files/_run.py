"""Run file format v1 (``.npz``): the unit of data everything else exchanges.

Keys (all required unless marked optional):

``format``          "omnisonar-run-1"
``sonar``           JSON text of the :class:`~mapping.signal.SonarConfig`
``samples``         float32 (n_blocks, block_samples): microphone signal, direct wave removed;
                    block k starts at sample k * block_samples of the run
``t_s``             float64 (n_blocks,): block start times in seconds
``speed_m_s``       float64 (n_blocks,): odometry speed over the block (negative = reversing)
``yaw_rate_rad_s``  float64 (n_blocks,): odometry yaw rate over the block
``pose``            float64 (n_blocks, 3): tracked x_m, y_m, heading_rad (direction of travel)
                    at the block midpoint; NaN rows where untracked
``scene``           optional JSON text of the scene the run was simulated in
``meta``            optional JSON text (engine, path, seed, ...)

Writes go to a temporary name in the same directory and are renamed into place, so an
interrupted write never leaves a corrupt file.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from mapping.files._atomic import atomic_savez
from mapping.files._npz import read_npz
from mapping.run import Run
from mapping.signal import SonarConfig

FORMAT = "omnisonar-run-1"


def write_run(path: str | os.PathLike[str], run: Run) -> Path:
    """Write ``run`` atomically to ``path`` (a ``.npz``); returns the final path."""
    path = Path(path)
    arrays: dict[str, Any] = {
        "format": np.array(FORMAT),
        "sonar": np.array(run.config.to_json()),
        "samples": run.samples,
        "t_s": run.t_s,
        "speed_m_s": run.speed_m_s,
        "yaw_rate_rad_s": run.yaw_rate_rad_s,
        "pose": run.pose,
        "meta": np.array(json.dumps(run.meta, sort_keys=True)),
    }
    if run.scene is not None:
        arrays["scene"] = np.array(run.scene)
    atomic_savez(path, arrays)
    return path


def read_run(path: str | os.PathLike[str]) -> Run:
    """Read and validate a run file; ``ValueError`` with the file and key on any problem."""
    path = Path(path)
    data = read_npz(path, FORMAT, "run",
                    ("sonar", "samples", "t_s", "speed_m_s", "yaw_rate_rad_s", "pose"))
    try:
        config = SonarConfig.from_json(str(data["sonar"]))
        meta = json.loads(str(data["meta"])) if "meta" in data else {}
        return Run(
            config=config,
            samples=np.asarray(data["samples"]),
            t_s=np.asarray(data["t_s"], dtype=np.float64),
            speed_m_s=np.asarray(data["speed_m_s"], dtype=np.float64),
            yaw_rate_rad_s=np.asarray(data["yaw_rate_rad_s"], dtype=np.float64),
            pose=np.asarray(data["pose"], dtype=np.float64),
            scene=str(data["scene"]) if "scene" in data else None,
            meta=meta,
        )
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
