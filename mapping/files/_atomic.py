"""Atomic file writes: write to a temporary name beside the target, then rename over it.

A killed process leaves either the old file or the new one, never a truncated file. The
temporary file lives in the target's directory (so ``os.replace`` is a rename on one file
system) and is removed on any failure, including ``KeyboardInterrupt``.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import numpy as np


def atomic_write(path: str | os.PathLike[str], write: Callable[[IO[bytes]], Any],
                 fsync: bool = True, private: bool = True) -> None:
    """Call ``write(fh)`` on a binary temporary file beside ``path``, then rename into place.

    Parameters
    ----------
    path
        Final file name; missing parent directories are created.
    write
        Writes the whole content to the open binary file handle it is given.
    fsync
        Flush and ``os.fsync`` before the rename (survives power loss; costs a disk flush).
    private
        Keep ``tempfile.mkstemp``'s owner-only ``0o600``; False gives the usual
        ``0o666 & ~umask`` of a file opened by name.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            if fsync:
                fh.flush()
                os.fsync(fh.fileno())
        if not private:
            os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes, fsync: bool = True) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_write`)."""
    atomic_write(path, lambda fh: fh.write(data), fsync=fsync)


def atomic_savez(path: str | os.PathLike[str], arrays: dict[str, Any],
                 fsync: bool = True) -> None:
    """``np.savez(**arrays)`` to ``path`` atomically (see :func:`atomic_write`)."""
    atomic_write(path, lambda fh: np.savez(fh, **arrays), fsync=fsync)


def _umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
