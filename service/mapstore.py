"""Maps served by the service: ``<maps_dir>/<map_id>.npz`` files in the map file format.

Reading, validating and writing map files is :mod:`mapping.mapfile`'s job; this module keeps
loaded maps cached (reloaded when the file changes), stores uploads atomically after
validating them, and renders the PNG preview (plotting lives at the edge).
"""

from __future__ import annotations

import io
import json
import os
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np

from mapping.signal import SonarConfig
from mapping.wallmap import WallMap


class MapNotFound(KeyError):
    """No map with this id (404)."""


class MapExists(Exception):
    """Upload or build onto an existing id without ``overwrite`` (409)."""


def _read_map(path: Path) -> WallMap:
    from mapping.files import read_map

    return read_map(path)


def _write_map(path: Path, wallmap: WallMap) -> None:
    from mapping.files import write_map

    write_map(path, wallmap)


def map_config(wallmap: WallMap) -> SonarConfig:
    """The SonarConfig a map was built with (Table 1 defaults when the map does not say)."""
    return SonarConfig.from_json(wallmap.sonar) if wallmap.sonar else SonarConfig()


class MapStore:
    """Maps by id, from a directory, cached in memory."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        directory.mkdir(parents=True, exist_ok=True)
        self._cache: dict[str, tuple[float, WallMap]] = {}
        self._lock = threading.Lock()

    def path(self, map_id: str) -> Path:
        return self.directory / f"{map_id}.npz"

    def ids(self) -> list[str]:
        return sorted(p.stem for p in self.directory.glob("*.npz") if not p.name.startswith("."))

    def exists(self, map_id: str) -> bool:
        return self.path(map_id).is_file()

    def get(self, map_id: str) -> WallMap:
        """The map ``map_id`` (cached; re-read if the file changed)."""
        path = self.path(map_id)
        try:
            mtime = path.stat().st_mtime
        except FileNotFoundError:
            raise MapNotFound(map_id) from None
        with self._lock:
            hit = self._cache.get(map_id)
            if hit is not None and hit[0] == mtime:
                return hit[1]
        wallmap = _read_map(path)
        with self._lock:
            self._cache[map_id] = (mtime, wallmap)
        return wallmap

    def info(self, map_id: str) -> dict[str, Any]:
        """Metadata for ``GET /maps/{id}``."""
        m = self.get(map_id)
        try:
            sonar: dict[str, Any] = json.loads(m.sonar) if m.sonar else {}
        except ValueError:
            sonar = {}
        return {
            "id": map_id,
            "shape": m.shape,
            "origin_m": (float(m.origin_m[0]), float(m.origin_m[1])),
            "resolution_m": float(m.resolution_m),
            "extent_m": tuple(float(v) for v in m.extent_m),
            "method": m.method,
            "params": _jsonable(m.params),
            "provenance": _jsonable(m.provenance),
            "sonar": sonar,
            "size_bytes": self.path(map_id).stat().st_size,
        }

    def save_upload(self, map_id: str, data: bytes, overwrite: bool = False) -> WallMap:
        """Validate ``data`` as a map file and store it as ``map_id`` atomically.

        Raises
        ------
        ValueError
            The bytes are not a valid map file (nothing is stored).
        MapExists
            ``map_id`` exists and ``overwrite`` is False.
        """
        if self.exists(map_id) and not overwrite:
            raise MapExists(map_id)
        fd, tmp = tempfile.mkstemp(prefix=f".{map_id}.", suffix=".upload.npz",
                                   dir=self.directory)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            wallmap = _read_map(Path(tmp))  # raises ValueError on a bad file
            if self.exists(map_id) and not overwrite:
                raise MapExists(map_id)
            os.replace(tmp, self.path(map_id))
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        return wallmap

    def put(self, map_id: str, wallmap: WallMap) -> None:
        """Write ``wallmap`` as ``map_id`` (the map file writer is atomic)."""
        _write_map(self.path(map_id), wallmap)

    def png(self, map_id: str) -> bytes:
        """A grey-scale PNG of G (north up, origin lower left)."""
        import matplotlib

        matplotlib.use("Agg")
        from matplotlib import pyplot as plt

        g = np.asarray(self.get(map_id).G, dtype=np.float64)
        top = float(np.percentile(g, 99.5)) if g.size else 1.0
        buf = io.BytesIO()
        low = float(g.min())
        plt.imsave(buf, g, cmap="gray_r", vmin=low, vmax=max(top, low + 1e-12), origin="lower",
                   format="png")
        return buf.getvalue()


def _jsonable(obj: Any) -> Any:
    """Plain JSON values (numpy scalars/arrays to Python)."""
    return json.loads(json.dumps(obj, default=_default))


def _default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)
