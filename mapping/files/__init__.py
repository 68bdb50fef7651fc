"""TODO docstring."""

from __future__ import annotations

from mapping.files._atomic import (
    atomic_savez,
    atomic_write,
    atomic_write_bytes,
)
from mapping.files._map import (
    file_sha256,
    read_map,
    read_pgm,
    write_map,
    write_ros_map,
)
from mapping.files._recording import (
    read_pose_csv,
    read_wav_mono,
    write_pose_csv,
    write_wav,
)
from mapping.files._run import (
    read_run,
    write_run,
)

__all__ = [
    "atomic_savez",
    "atomic_write",
    "atomic_write_bytes",
    "file_sha256",
    "read_map",
    "read_pgm",
    "read_pose_csv",
    "read_run",
    "read_wav_mono",
    "write_map",
    "write_pose_csv",
    "write_ros_map",
    "write_run",
    "write_wav",
]
