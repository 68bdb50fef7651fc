"""The sensor model: the likelihood of a heat map given a pose and the wall map G.

At a pose the map predicts what the sonar should hear by sampling G on a polar grid around it
(the inverse of the paper's eqs. 2-4); the measured heat map (eq. 1), which only knows
``|angle|``, is unfolded onto the same grid with both mirror sides equal, and the score is the
Pearson correlation ``rho`` of the two. Three models (`Model`): ``correlation`` and ``range``
(range profile only; heading-free, used automatically when the robot is too slow for the
Doppler bank) score against G; ``echo`` is the physical model on the map's walls (the
forward model's echoes against the heat map's peaks, `explanation`), scored in the same
units (``rho = 1 + ll / ECHO_NATS``); it reads the map's own uncertainty, each echo's range
widened by its walls' fit sigma (`map_range_sigma`) and free wall ends known only to their
endpoint sigma (`soft_end_walls`, `end_weights`). The likelihood is tempered and floored,
``log((1 - z_rand) exp(beta (rho - rho_best)) + z_rand)``.

Entry points: `SensorConfig`; `build_tables` (`SensorTables`: lookup tables of one map) and
`free_space_mask`; `prepare_measurement` (`Measurement`: a heat map checked and reduced to its
strongest entries), `heatmap_run` (a run with the sonar settings the model's heat maps are
made with: the echo model reads a denser bank, `SensorConfig.heatmap_sonar`),
`validate_block`, `validate_heatmap`, `uses_direction`; scoring
`score_poses`, `score_cells_all_headings` (every heading at once by FFT), `log_likelihood`,
`pose_log_likelihood`, `polar_prediction`; `predicted_echoes` (the echo model's forward
prediction at poses, used by the refinement).

Notes
-----
Private modules: ``_config`` (`SensorConfig`), ``_tables`` (lookup tables, free space),
``_measurement`` (checking and preparing a measurement), ``_scoring`` (the model and its
likelihood), ``_echo`` (the echo model), ``_kernels`` (serial numba kernels; their numpy
twins live in the tests, ``tests/localization/sensor/naive.py``).
"""

from __future__ import annotations

from localization.sensor._config import (
    ECHO_NATS,
    Model,
    SensorConfig,
)
from localization.sensor._echo import (
    Explanation,
    cos_sigma,
    echo_proposals,
    explanation,
    map_range_sigma,
    pair_proposals,
    predicted_echoes,
)
from localization.sensor._measurement import (
    Measurement,
    heatmap_run,
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
)
from localization.sensor._tables import (
    SensorTables,
    build_tables,
    end_weights,
    free_space_mask,
    resolve_model,
    soft_end_walls,
    symmetric_poses,
    uniform_free_poses,
    wall_symmetries,
)

__all__ = [
    "ECHO_NATS",
    "Explanation",
    "heatmap_run",
    "cos_sigma",
    "echo_proposals",
    "pair_proposals",
    "end_weights",
    "explanation",
    "map_range_sigma",
    "predicted_echoes",
    "soft_end_walls",
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
    "resolve_model",
    "score_poses",
    "symmetric_poses",
    "wall_symmetries",
    "uniform_free_poses",
    "uses_direction",
    "validate_block",
    "validate_heatmap",
]
