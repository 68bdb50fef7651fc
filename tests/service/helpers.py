"""Helpers shared by the service tests: a rasterized wall map and a tracked session request."""

from __future__ import annotations

import math
from typing import Any

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



MAP_KEYS = ("G", "origin_m", "resolution_m", "sonar", "method", "params", "provenance",
            "walls_m", "wall_strength", "wall_sigma", "wall_ambiguous", "wall_pair", "coverage")


def map_arrays(wallmap: WallMap | None = None) -> dict[str, Any]:
    """The arrays of a map file (format omnisonar-map-2, docs/formats.md), without checksum."""
    import json

    m = wallmap or raster_map()
    return {"G": m.G, "origin_m": np.asarray(m.origin_m),
            "resolution_m": np.float64(m.resolution_m),
            "sonar": np.array(m.sonar), "method": np.array(m.method),
            "params": np.array(json.dumps(m.params)),
            "provenance": np.array(json.dumps(m.provenance)), "walls_m": m.walls_m,
            "wall_strength": m.wall_strength, "wall_sigma": m.wall_sigma,
            "wall_ambiguous": m.wall_ambiguous, "wall_pair": m.wall_pair, "coverage": m.coverage}


def map_file_bytes(arrays: dict[str, Any] | None = None, compressed: bool = False) -> bytes:
    """A map file of ``arrays`` (any values: an attacker's file) with a *valid* checksum,
    computed here from the format's documentation, independently of the writer."""
    import hashlib
    import io

    arrays = dict(map_arrays() if arrays is None else arrays)
    h = hashlib.sha256(b"omnisonar-map-2")
    for key in MAP_KEYS:
        a = np.asarray(arrays[key])
        data = str(a).encode() if a.dtype.kind == "U" else np.ascontiguousarray(a).tobytes()
        h.update(f"|{key}|{a.dtype.str}|{a.shape}|".encode())
        h.update(data)
    arrays["format"] = np.array("omnisonar-map-2")
    arrays["checksum"] = np.array(h.hexdigest())
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return buf.getvalue()
