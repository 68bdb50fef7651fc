"""Fixtures shared across the test tree.

``simulated``: a wall map G from an image-source L-room mapping run and a held-out run of
the same room (session scope: several slow tests in localization/ and service/ use it).

Hypothesis runs derandomized (each property test's examples follow from its name), so that
``make test`` and CI give the same result on every run: two property tests failed at random
seeds on examples their strategies did not mean to draw (fixed). ``HYPOTHESIS_EXPLORE=1``
draws fresh random examples, to look for such cases."""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import settings

settings.register_profile("reproducible", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile("explore" if os.environ.get("HYPOTHESIS_EXPLORE") else "reproducible")


@pytest.fixture(scope="session")
def simulated() -> tuple[object, object]:
    """Map G from an L-room mapping run and a held-out run (image sources, order 2)."""
    from mapping.build import BuildParams, RunSource, build_map
    from mapping.path import builtin_path
    from mapping.scene import builtin_scene
    from mapping.signal import SonarConfig
    from mapping.simulate import simulate_run
    from mapping.simulate.ism import IsmConfig

    config, scene = SonarConfig(), builtin_scene("l-room")
    mapping_run = simulate_run(scene, builtin_path("l-room-curve", 0.1), config, 56,
                               IsmConfig(order=2, snr_db=20.0), np.random.default_rng(0), 0)
    wall_map = build_map([RunSource.from_run(mapping_run)], BuildParams())
    held = simulate_run(scene, builtin_path("l-room-curve", 0.15), config, 38,
                        IsmConfig(order=2, snr_db=20.0, odometry_noise_m_s=0.005),
                        np.random.default_rng(1), 1)
    return wall_map, held
