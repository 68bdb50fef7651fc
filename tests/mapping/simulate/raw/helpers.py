"""Shared scenes, paths and truths of the raw-simulator tests."""

from __future__ import annotations

import json

import numpy as np

from mapping.path import polyline_path, stationary_path
from mapping.scene import Scene
from mapping.signal import SonarConfig, transmitted_exact
from mapping.simulate.ism import IsmConfig

CFG = SonarConfig(repetitions=1)  # P = 4092 samples, 0.1023 s
ENGINE = IsmConfig()
WALL_X_M = 2.0  # one wall, x = 2 m, from y = -30 to 30 m
REFLECTION = 0.8


def one_wall(reflection: float = REFLECTION) -> Scene:
    """A single long wall at x = WALL_X_M."""
    wall = {"name": "w", "start": [WALL_X_M, -30.0], "end": [WALL_X_M, 30.0],
            "reflection": reflection}
    return Scene.from_json(json.dumps({"name": "one-wall", "walls": [wall]}))


def standing(duration_s: float = 5.0):
    """A robot standing at the origin facing +y (1-D range to the wall: WALL_X_M)."""
    return stationary_path([0.0, 0.0], np.pi / 2, duration_s)


def driving(speed_m_s: float = 0.3):
    """A robot driving from the origin towards the wall (x) at ``speed_m_s``."""
    return polyline_path([(0.0, 0.5), (1.5, 0.5)], speed_m_s=speed_m_s)


def echo(delay_s: float, gain: float, tau_s: np.ndarray) -> np.ndarray:
    """``gain * s(tau - delay)``, the exact band-limited transmitted signal, delayed."""
    return gain * transmitted_exact(np.asarray(tau_s) - delay_s, CFG)
