"""Map file format ``omnisonar-map-1`` (``.npz``) and the ROS map_server export (PGM + YAML).

Keys of the ``.npz`` (all required):

``format``        "omnisonar-map-1"
``G``             float64 (ny, nx): the map; ``G[iy, ix]`` is the cell centred at
                  ``origin_m + resolution_m * (ix, iy)``
``origin_m``      float64 (2,): world x, y of the centre of cell ``G[0, 0]``, metres
``resolution_m``  float64 scalar: cell size, metres
``sonar``         JSON text of the SonarConfig the runs were recorded with
``method``        reconstruction method ("paper", "inverse", ...)
``params``        JSON text of the method parameters
``provenance``    JSON text: input run files with their SHA-256, block counts, tool version
``checksum``      SHA-256 (hex) over every other key (see :func:`content_checksum`)

Writes are atomic (temporary name in the same directory, then rename). Reading refuses a
truncated file, a foreign format, a missing key or a checksum mismatch with ``ValueError``.

The ROS export follows map_server's conventions: an 8-bit binary PGM (``P5``) whose first
row is the *top* of the map (largest y), and a YAML with ``image``, ``resolution``,
``origin`` (x, y, yaw of the *lower-left corner* of the lower-left pixel), ``negate: 0``,
``occupied_thresh`` and ``free_thresh``. The occupancy-like value of a cell is
``clip(G / (scale_fraction * p99(G > 0)), 0, 1)`` and the pixel is ``255 * (1 - value)``
(dark = wall evidence), which map_server reads back as ``p = (255 - pixel) / 255``.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mapping.files._atomic import atomic_savez, atomic_write_bytes
from mapping.files._npz import read_npz
from mapping.wallmap import WallMap

FORMAT = "omnisonar-map-1"
_KEYS = ("G", "origin_m", "resolution_m", "sonar", "method", "params", "provenance")


def _fields(wallmap: WallMap) -> dict[str, Any]:
    return {
        "G": np.ascontiguousarray(wallmap.G, dtype=np.float64),
        "origin_m": np.asarray(wallmap.origin_m, dtype=np.float64),
        "resolution_m": np.float64(wallmap.resolution_m),
        "sonar": np.array(wallmap.sonar),
        "method": np.array(wallmap.method),
        "params": np.array(json.dumps(wallmap.params, sort_keys=True)),
        "provenance": np.array(json.dumps(wallmap.provenance, sort_keys=True)),
    }


def content_checksum(arrays: dict[str, Any]) -> str:
    """SHA-256 over the format string and every key of ``_KEYS`` (name, dtype, shape, bytes)."""
    h = hashlib.sha256(FORMAT.encode())
    for key in _KEYS:
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
    """Write ``wallmap`` atomically to ``path`` (``.npz``); returns the final path."""
    path = Path(path)
    arrays = _fields(wallmap)
    arrays["format"] = np.array(FORMAT)
    arrays["checksum"] = np.array(content_checksum(arrays))
    atomic_savez(path, arrays)
    return path


def read_map(path: str | os.PathLike[str]) -> WallMap:
    """Read and verify a map file; ``ValueError`` naming the file and the problem."""
    path = Path(path)
    data = read_npz(path, FORMAT, "map", (*_KEYS, "checksum"))
    if content_checksum(data) != str(data["checksum"]):
        raise ValueError(f"{path}: checksum mismatch: the file was altered or corrupted")
    try:
        origin = np.asarray(data["origin_m"], dtype=np.float64)
        if origin.shape != (2,):
            raise ValueError(f"origin_m must have shape (2,), got {origin.shape}")
        return WallMap(
            G=np.asarray(data["G"], dtype=np.float64),
            origin_m=(float(origin[0]), float(origin[1])),
            resolution_m=float(data["resolution_m"]),
            sonar=str(data["sonar"]),
            method=str(data["method"]),
            params=json.loads(str(data["params"])),
            provenance=json.loads(str(data["provenance"])),
        )
    except (ValueError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: {exc}") from exc


# ---- ROS map_server export ------------------------------------------------------------
def occupancy_pgm_bytes(G: NDArray[np.float64], scale_fraction: float = 0.5) -> bytes:
    """8-bit binary PGM of ``G`` (top row = largest y), dark where wall evidence is strong."""
    if not scale_fraction > 0:
        raise ValueError(f"scale_fraction must be > 0, got {scale_fraction}")
    pos = G[G > 0]
    scale = scale_fraction * float(np.percentile(pos, 99)) if pos.size else 1.0
    value = np.clip(G / scale, 0.0, 1.0)
    pixels = np.round(255.0 * (1.0 - value)).astype(np.uint8)[::-1, :]
    header = f"P5\n# omnisonar wall map\n{pixels.shape[1]} {pixels.shape[0]}\n255\n".encode()
    return header + pixels.tobytes()


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
    """Write ``NAME.pgm`` and ``NAME.yaml`` (map_server format); returns both paths."""
    pgm = Path(pgm_path)
    if pgm.suffix.lower() != ".pgm":
        raise ValueError(f"pgm_path must end in .pgm, got {pgm}")
    yaml = pgm.with_suffix(".yaml")
    atomic_write_bytes(pgm, occupancy_pgm_bytes(wallmap.G, scale_fraction))
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
