"""Helpers shared by the service tests: a rasterized wall map and a tracked session request."""

from __future__ import annotations

import math

import numpy as np

from mapping.scene import builtin_scene
from mapping.signal import SonarConfig
from mapping.wallmap import WallMap


def raster_map(scene: str = "shoebox", res: float = 0.05, margin: float = 0.3) -> WallMap:
    """G = 1 on the cells crossed by the scene's walls, 0 elsewhere."""
    segs = builtin_scene(scene).segments().reshape(-1, 4)
    x0, y0 = segs[:, [0, 2]].min() - margin, segs[:, [1, 3]].min() - margin
    x1, y1 = segs[:, [0, 2]].max() + margin, segs[:, [1, 3]].max() + margin
    G = np.zeros((int(round((y1 - y0) / res)) + 1, int(round((x1 - x0) / res)) + 1))
    for xa, ya, xb, yb in segs:
        t = np.linspace(0, 1, int(math.hypot(xb - xa, yb - ya) / (res / 4)) + 2)
        ix = np.rint((xa + t * (xb - xa) - x0) / res).astype(int)
        iy = np.rint((ya + t * (yb - ya) - y0) / res).astype(int)
        G[iy, ix] = 1.0
    return WallMap(G=G, origin_m=(x0, y0), resolution_m=res, sonar=SonarConfig().to_json(),
                   method="raster", provenance={"scene": scene})


TRACKED = {"map_id": "room", "particles": 300, "seed": 1,
           "initial_pose": {"x": 1.0, "y": 1.5, "yaw": 0.0},
           "initial_covariance": [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.03]]}
