"""The project's file formats: the only place under ``mapping`` that reads or writes files.

Run files (``omnisonar-run-1``, `read_run` / `write_run`: blocks, odometry and tracked
poses of a `mapping.run.Run`), map files (``omnisonar-map-2``, `read_map` / `write_map`,
with a SHA-256 checksum, and `file_sha256`; `read_map` reads ``omnisonar-map-1`` too), the
ROS map_server export (`write_ros_map`, rasterized from the walls when the map has walls;
`read_pgm`), GeoJSON of the walls (`write_geojson`), and the files of real recordings (mono
WAV, `read_wav_mono` / `write_wav`; raw WAVs at any rate, `read_wav_raw`; the pose-log CSV,
`read_pose_csv` / `write_pose_csv`).
Every writer goes through the atomic writes (`atomic_write`, `atomic_write_bytes`,
`atomic_savez`): a temporary name beside the target, then a rename, so a killed process leaves
the old file or the new one, never a truncated file. Readers refuse a foreign or truncated file
with a ``ValueError`` naming it.

Notes
-----
Private modules: ``_run`` (run file v1), ``_map`` (map file v1/v2, PGM/YAML and GeoJSON),
``_recording`` (WAV and pose CSV), ``_npz`` (reading the versioned ``.npz`` containers),
``_atomic`` (atomic writes). The keys of each format are listed in the documentation
(``docs/formats.md``).
"""

from __future__ import annotations

from mapping.files._atomic import (
    atomic_savez,
    atomic_write,
    atomic_write_bytes,
)
from mapping.files._json import json_safe
from mapping.files._map import (
    file_sha256,
    read_map,
    read_pgm,
    write_geojson,
    write_map,
    write_ros_map,
)
from mapping.files._recording import (
    RawWav,
    read_pose_csv,
    read_wav_mono,
    read_wav_raw,
    write_pose_csv,
    write_wav,
)
from mapping.files._run import (
    read_run,
    write_run,
)

__all__ = [
    "json_safe",
    "atomic_savez",
    "atomic_write",
    "atomic_write_bytes",
    "file_sha256",
    "read_map",
    "read_pgm",
    "read_pose_csv",
    "read_run",
    "read_wav_mono",
    "read_wav_raw",
    "RawWav",
    "write_geojson",
    "write_map",
    "write_pose_csv",
    "write_ros_map",
    "write_run",
    "write_wav",
]
