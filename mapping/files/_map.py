"""Map file format ``omnisonar-map-2`` (``.npz``; reads ``omnisonar-map-1`` too) and the
exports: ROS map_server (PGM + YAML) and GeoJSON of the walls.

Keys of the ``.npz`` (all required; version 1 files have only the first block):

``format``          "omnisonar-map-2" (or "omnisonar-map-1")
``G``               float64 (ny, nx): the map; ``G[iy, ix]`` is the cell centred at
                    ``origin_m + resolution_m * (ix, iy)``
``origin_m``        float64 (2,): world x, y of the centre of cell ``G[0, 0]``, metres
``resolution_m``    float64 scalar: cell size, metres
``sonar``           JSON text of the SonarConfig the runs were recorded with
``method``          reconstruction method ("walls", "paper", "inverse")
``params``          JSON text of the method parameters
``provenance``      JSON text: input run files with their SHA-256, block counts, tool version

Version 2 only:

``walls_m``         float64 (n, 4): fitted walls x0, y0, x1, y1 in metres (n may be 0)
``wall_strength``   float64 (n,): reflection strength
``wall_sigma``      float64 (n, 3): 1-sigma of (normal offset m, angle rad, endpoint m); NaN
                    where not estimated
``wall_ambiguous``  bool (n,): kept with its mirror hypothesis (straight path)
``wall_pair``       int64 (n,): index of the mirror hypothesis, or -1
``coverage``        bool (ny, nx): cells the runs observed

``checksum``        SHA-256 (hex) over every other key (see :func:`content_checksum`)

A version 1 file reads as a map with no walls and every cell observed. Writes are atomic
(temporary name in the same directory, then rename) and always version 2. Reading refuses a
truncated file, a foreign format, a missing key or a checksum mismatch with ``ValueError``.

The ROS export follows map_server's conventions: an 8-bit binary PGM (``P5``) whose first
row is the *top* of the map (largest y), and a YAML with ``image``, ``resolution``,
``origin`` (x, y, yaw of the *lower-left corner* of the lower-left pixel), ``negate: 0``,
``occupied_thresh`` and ``free_thresh``; map_server reads a pixel back as
``p = (255 - pixel) / 255``. A map **with walls** is rasterized from them: 0 (occupied) on every
cell a wall passes through, 254 (free) on the other observed cells, 205 (unknown, between the
thresholds) outside coverage. A map without walls is drawn from G: the occupancy-like value
``clip(G / (scale_fraction * p99(G > 0)), 0, 1)`` becomes the pixel ``255 * (1 - value)``.

The GeoJSON export is a ``FeatureCollection`` with one ``LineString`` per wall whose
coordinates are **metres in the map frame** (x, y), not longitude/latitude; the collection says
so in its ``frame`` and ``units`` members (RFC 7946 allows such foreign members).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.files._atomic import atomic_savez, atomic_write_bytes
from mapping.files._npz import read_npz
from mapping.wallmap import WallMap, rasterize_walls

FORMAT = "omnisonar-map-2"
FORMAT_V1 = "omnisonar-map-1"
_KEYS_V1 = ("G", "origin_m", "resolution_m", "sonar", "method", "params", "provenance")
_KEYS = (*_KEYS_V1, "walls_m", "wall_strength", "wall_sigma", "wall_ambiguous", "wall_pair",
         "coverage")
_KEYS_OF = {FORMAT: _KEYS, FORMAT_V1: _KEYS_V1}

#: map_server pixel values of the wall raster: occupied, free, unknown.
PIXEL_OCCUPIED, PIXEL_FREE, PIXEL_UNKNOWN = 0, 254, 205


def _fields(wallmap: WallMap) -> dict[str, Any]:
    return {
        "G": np.ascontiguousarray(wallmap.G, dtype=np.float64),
        "origin_m": np.asarray(wallmap.origin_m, dtype=np.float64),
        "resolution_m": np.float64(wallmap.resolution_m),
        "sonar": np.array(wallmap.sonar),
        "method": np.array(wallmap.method),
        "params": np.array(json.dumps(wallmap.params, sort_keys=True)),
        "provenance": np.array(json.dumps(wallmap.provenance, sort_keys=True)),
        "walls_m": np.ascontiguousarray(wallmap.walls_m, dtype=np.float64),
        "wall_strength": np.ascontiguousarray(wallmap.wall_strength, dtype=np.float64),
        "wall_sigma": np.ascontiguousarray(wallmap.wall_sigma, dtype=np.float64),
        "wall_ambiguous": np.ascontiguousarray(wallmap.wall_ambiguous, dtype=np.bool_),
        "wall_pair": np.ascontiguousarray(wallmap.wall_pair, dtype=np.int64),
        "coverage": np.ascontiguousarray(wallmap.coverage, dtype=np.bool_),
    }


def content_checksum(arrays: dict[str, Any], format_name: str = FORMAT) -> str:
    """SHA-256 over the format string and every key of that format (name, dtype, shape, bytes).

    ``format_name`` selects the key set: version 2 (default) or ``"omnisonar-map-1"``.
    """
    h = hashlib.sha256(format_name.encode())
    for key in _KEYS_OF[format_name]:
        a = np.asarray(arrays[key])
        if a.dtype.kind == "U":
            data = str(a).encode("utf-8")
        else:
            data = np.ascontiguousarray(a).tobytes()
        h.update(f"|{key}|{a.dtype.str}|{a.shape}|".encode())
        h.update(data)
    return h.hexdigest()


def file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 (hex) of a file's bytes, for provenance."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def write_map(path: str | os.PathLike[str], wallmap: WallMap) -> Path:
    """Write ``wallmap`` atomically to ``path`` (``.npz``, ``omnisonar-map-2``); returns it."""
    path = Path(path)
    arrays = _fields(wallmap)
    arrays["format"] = np.array(FORMAT)
    arrays["checksum"] = np.array(content_checksum(arrays))
    atomic_savez(path, arrays)
    return path


def read_map(path: str | os.PathLike[str]) -> WallMap:
    """Read and verify a map file (version 2 or 1); ``ValueError`` naming the file and problem.

    A version 1 file has no walls and reads with every cell observed.
    """
    path = Path(path)
    data = read_npz(path, (FORMAT, FORMAT_V1), "map", ("checksum",))
    fmt = str(data["format"])
    missing = [k for k in _KEYS_OF[fmt] if k not in data]
    if missing:
        raise ValueError(f"{path}: missing key(s) {missing}")
    if content_checksum(data, fmt) != str(data["checksum"]):
        raise ValueError(f"{path}: checksum mismatch: the file was altered or corrupted")
    try:
        origin = np.asarray(data["origin_m"], dtype=np.float64)
        if origin.shape != (2,):
            raise ValueError(f"origin_m must have shape (2,), got {origin.shape}")
        walls: dict[str, Any] = {}
        if fmt == FORMAT:
            walls = {k: np.asarray(data[k]) for k in _KEYS[len(_KEYS_V1):]}
        return WallMap(
            G=np.asarray(data["G"], dtype=np.float64),
            origin_m=(float(origin[0]), float(origin[1])),
            resolution_m=float(data["resolution_m"]),
            sonar=str(data["sonar"]),
            method=str(data["method"]),
            params=json.loads(str(data["params"])),
            provenance=json.loads(str(data["provenance"])),
            **walls,
        )
    except (ValueError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: {exc}") from exc


# ---- ROS map_server export ------------------------------------------------------------
def _pgm_bytes(pixels_bottom_up: NDArray[np.uint8]) -> bytes:
    pixels = np.ascontiguousarray(pixels_bottom_up[::-1, :])
    header = f"P5\n# omnisonar wall map\n{pixels.shape[1]} {pixels.shape[0]}\n255\n".encode()
    return header + pixels.tobytes()


def occupancy_pgm_bytes(G: NDArray[np.float64], scale_fraction: float = 0.5) -> bytes:
    """8-bit binary PGM of ``G`` (top row = largest y), dark where wall evidence is strong."""
    if not scale_fraction > 0:
        raise ValueError(f"scale_fraction must be > 0, got {scale_fraction}")
    pos = G[G > 0]
    scale = scale_fraction * float(np.percentile(pos, 99)) if pos.size else 1.0
    value = np.clip(G / scale, 0.0, 1.0)
    return _pgm_bytes(np.round(255.0 * (1.0 - value)).astype(np.uint8))


def wall_pixels(wallmap: WallMap) -> NDArray[np.uint8]:
    """map_server pixels of the walls, shape (ny, nx), row 0 = smallest y (as ``G``).

    ``PIXEL_OCCUPIED`` on every cell a wall passes through, ``PIXEL_FREE`` on the other observed
    cells (``coverage``), ``PIXEL_UNKNOWN`` elsewhere.
    """
    pixels = np.where(wallmap.coverage, PIXEL_FREE, PIXEL_UNKNOWN).astype(np.uint8)
    pixels[rasterize_walls(wallmap.walls_m, wallmap.x_m, wallmap.y_m)] = PIXEL_OCCUPIED
    return pixels


def ros_yaml_text(wallmap: WallMap, image_name: str, occupied_thresh: float = 0.65,
                  free_thresh: float = 0.196) -> str:
    """map_server YAML for the PGM ``image_name`` (origin = lower-left corner of the map)."""
    xmin, _, ymin, _ = wallmap.extent_m
    return (
        f"image: {image_name}\n"
        f"resolution: {wallmap.resolution_m:.6f}\n"
        f"origin: [{xmin:.6f}, {ymin:.6f}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {occupied_thresh}\n"
        f"free_thresh: {free_thresh}\n"
    )


def write_ros_map(pgm_path: str | os.PathLike[str], wallmap: WallMap,
                  scale_fraction: float = 0.5) -> tuple[Path, Path]:
    """Write ``NAME.pgm`` and ``NAME.yaml`` (map_server format); returns both paths.

    Rasterized from the walls when the map has any (``scale_fraction`` is then unused), from G
    otherwise (see the module docstring for the pixel values).
    """
    pgm = Path(pgm_path)
    if pgm.suffix.lower() != ".pgm":
        raise ValueError(f"pgm_path must end in .pgm, got {pgm}")
    yaml = pgm.with_suffix(".yaml")
    if wallmap.n_walls:
        data = _pgm_bytes(wall_pixels(wallmap))
    else:
        data = occupancy_pgm_bytes(wallmap.G, scale_fraction)
    atomic_write_bytes(pgm, data)
    atomic_write_bytes(yaml, ros_yaml_text(wallmap, pgm.name).encode())
    return pgm, yaml


def read_pgm(path: str | os.PathLike[str]) -> NDArray[np.uint8]:
    """Read an 8-bit binary PGM (as written by :func:`write_ros_map`), rows top to bottom."""
    raw = Path(path).read_bytes()
    fields: list[bytes] = []
    pos = 0
    while len(fields) < 4:
        while raw[pos:pos + 1].isspace():
            pos += 1
        if raw[pos:pos + 1] == b"#":
            pos = raw.index(b"\n", pos) + 1
            continue
        end = pos
        while not raw[end:end + 1].isspace():
            end += 1
        fields.append(raw[pos:end])
        pos = end
    if fields[0] != b"P5" or int(fields[3]) != 255:
        raise ValueError(f"{path}: not an 8-bit binary PGM")
    w, h = int(fields[1]), int(fields[2])
    data = np.frombuffer(raw[pos + 1:pos + 1 + w * h], dtype=np.uint8)
    if data.size != w * h:
        raise ValueError(f"{path}: truncated PGM")
    return data.reshape(h, w)


# ---- GeoJSON export ---------------------------------------------------------------------
def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def walls_geojson(wallmap: WallMap) -> dict[str, Any]:
    """The walls as a GeoJSON ``FeatureCollection`` (a plain dict; coordinates in map metres).

    One ``LineString`` feature per wall, in the map's order, with properties ``index``,
    ``strength``, ``sigma`` (``normal_offset_m``, ``angle_rad``, ``endpoint_m``; null where not
    estimated), ``ambiguous`` and ``pair`` (index of the mirror hypothesis, or null).
    """
    features = []
    for i in range(wallmap.n_walls):
        x0, y0, x1, y1 = (float(v) for v in wallmap.walls_m[i])
        s = wallmap.wall_sigma[i]
        pair = int(wallmap.wall_pair[i])
        features.append({
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": [[x0, y0], [x1, y1]]},
            "properties": {
                "index": i,
                "strength": float(wallmap.wall_strength[i]),
                "sigma": {"normal_offset_m": _finite_or_none(s[0]),
                          "angle_rad": _finite_or_none(s[1]),
                          "endpoint_m": _finite_or_none(s[2])},
                "ambiguous": bool(wallmap.wall_ambiguous[i]),
                "pair": pair if pair >= 0 else None,
            },
        })
    return {
        "type": "FeatureCollection",
        "frame": "map",
        "units": "m",
        "note": "coordinates are x, y in metres in the map's local frame (the frame of the "
                "run poses), not longitude/latitude",
        "method": wallmap.method,
        "features": features,
    }


def write_geojson(path: str | os.PathLike[str], wallmap: WallMap) -> Path:
    """Write the walls as GeoJSON (see :func:`walls_geojson`) atomically; returns the path."""
    path = Path(path)
    text = json.dumps(walls_geojson(wallmap), indent=1, allow_nan=False)
    atomic_write_bytes(path, (text + "\n").encode())
    return path
