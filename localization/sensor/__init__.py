"""TODO docstring."""

from __future__ import annotations

from localization.sensor._config import (
    Model,
    SensorConfig,
)
from localization.sensor._measurement import (
    Measurement,
    prepare_measurement,
    uses_direction,
    validate_block,
    validate_heatmap,
)
from localization.sensor._scoring import (
    OFF_MAP_PENALTY,
    cell_polar_samples,
    log_likelihood,
    polar_prediction,
    pose_log_likelihood,
    score_cells_all_headings,
    score_poses,
    score_poses_numpy,
)
from localization.sensor._tables import (
    SensorTables,
    build_tables,
    free_space_mask,
)

__all__ = [
    "Measurement",
    "Model",
    "OFF_MAP_PENALTY",
    "SensorConfig",
    "SensorTables",
    "build_tables",
    "cell_polar_samples",
    "free_space_mask",
    "log_likelihood",
    "polar_prediction",
    "pose_log_likelihood",
    "prepare_measurement",
    "score_cells_all_headings",
    "score_poses",
    "score_poses_numpy",
    "uses_direction",
    "validate_block",
    "validate_heatmap",
]
