"""Maps served by the service: ``<maps_dir>/<map_id>.npz`` files in the map file format.

Reading and writing map files is :mod:`mapping.files`' job; this module keeps loaded maps
(weakly: a map's memory is released when no session holds it), names each stored map by the
SHA-256 of its file (sessions pin that hash), validates uploads completely before storing
them (headers first, :mod:`service.npzcheck`, then every value: only a map that can be served
is stored), removes temporary files a killed upload left behind, and renders the PNG preview.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import re
import secrets
import tempfile
import threading
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mapping.signal import SonarConfig
from mapping.wallmap import WallMap
from service.npzcheck import MapRejected, check_map_headers
from service.schemas import MAX_COORD_M

#: Cell sizes an upload may have, metres.
MIN_RESOLUTION_M, MAX_RESOLUTION_M = 1e-3, 10.0
#: Suffix of in-flight uploads (``.<id>.<random>.upload.npz``), removed at start-up.
UPLOAD_SUFFIX = ".upload.npz"


#: A map key named in a reader's message ("WallMap.resolution_m must be > 0", ...).
_KEY_IN_MESSAGE = re.compile(r"\b(G|origin_m|resolution_m|sonar|method|params|provenance|"
                             r"walls_m|wall_strength|wall_sigma|wall_ambiguous|wall_pair|"
                             r"coverage)\b")


class MapNotFound(KeyError):
    """No map with this id (404)."""


class MapExists(Exception):
    """Upload or build onto an existing id without ``overwrite`` (409)."""


class MapInUse(Exception):
    """Delete of a map that live sessions (or a running build) still use (409)."""

    def __init__(self, map_id: str, detail: str) -> None:
        super().__init__(detail)
        self.map_id = map_id


def _read_map(path: Path) -> WallMap:
    from mapping.files import read_map

    return read_map(path)


def _write_map(path: Path, wallmap: WallMap) -> None:
    from mapping.files import write_map

    write_map(path, wallmap)


def map_config(wallmap: WallMap) -> SonarConfig:
    """The SonarConfig a map was built with (Table 1 defaults when the map does not say)."""
    return SonarConfig.from_json(wallmap.sonar) if wallmap.sonar else SonarConfig()


@dataclass(frozen=True)
class _Version:
    """Identity of one file version (``os.replace`` makes a new inode)."""

    ino: int
    mtime_ns: int
    size: int

    @classmethod
    def of(cls, path: Path) -> _Version:
        st = path.stat()
        return cls(st.st_ino, st.st_mtime_ns, st.st_size)


class MapStore:
    """Maps by id, from a directory; loaded maps are shared while in use, then released."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        directory.mkdir(parents=True, exist_ok=True)
        self._maps: weakref.WeakValueDictionary[tuple[str, _Version], WallMap]
        self._maps = weakref.WeakValueDictionary()
        self._digests: dict[str, tuple[_Version, str]] = {}
        self._infos: dict[str, tuple[_Version, dict[str, Any]]] = {}
        self._lock = threading.Lock()

    def path(self, map_id: str) -> Path:
        return self.directory / f"{map_id}.npz"

    def ids(self) -> list[str]:
        return sorted(p.stem for p in self.directory.glob("*.npz") if not p.name.startswith("."))

    def exists(self, map_id: str) -> bool:
        return self.path(map_id).is_file()

    def clean_orphans(self) -> list[str]:
        """Remove temporary files of uploads and writes a killed process left (start-up)."""
        gone = []
        for p in self.directory.iterdir():
            if p.name.startswith(".") and (p.name.endswith(UPLOAD_SUFFIX)
                                           or p.name.endswith(".tmp")):
                p.unlink(missing_ok=True)
                gone.append(p.name)
        return gone

    def _version(self, map_id: str) -> _Version:
        try:
            return _Version.of(self.path(map_id))
        except FileNotFoundError:
            raise MapNotFound(map_id) from None

    def load(self, map_id: str) -> tuple[WallMap, str]:
        """The map ``map_id`` and the SHA-256 of its file, read from one file version."""
        for _ in range(5):  # retried when the file is replaced while it is read
            version = self._version(map_id)
            digest = self.digest(map_id)
            with self._lock:
                wallmap = self._maps.get((map_id, version))
            if wallmap is None:
                wallmap = _read_map(self.path(map_id))
            if self._version(map_id) == version and self.digest(map_id) == digest:
                with self._lock:
                    self._maps[(map_id, version)] = wallmap
                return wallmap, digest
        raise MapNotFound(map_id)  # replaced five times in a row: try again later

    def get(self, map_id: str) -> WallMap:
        """The map ``map_id`` (shared while some caller holds it; re-read if the file changed)."""
        return self.load(map_id)[0]

    def digest(self, map_id: str) -> str:
        """SHA-256 (hex) of the stored file of ``map_id`` (cached per file version)."""
        version = self._version(map_id)
        with self._lock:
            hit = self._digests.get(map_id)
        if hit is not None and hit[0] == version:
            return hit[1]
        h = hashlib.sha256()
        with open(self.path(map_id), "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
        with self._lock:
            self._digests[map_id] = (version, h.hexdigest())
        return h.hexdigest()

    def info(self, map_id: str) -> dict[str, Any]:
        """Metadata for ``GET /maps/{id}`` (cached per file version; small)."""
        version = self._version(map_id)
        with self._lock:
            hit = self._infos.get(map_id)
        if hit is not None and hit[0] == version:
            return hit[1]
        wallmap, digest = self.load(map_id)
        out = map_info(map_id, wallmap, version.size, digest)
        with self._lock:
            self._infos[map_id] = (version, out)
        return out

    def save_upload(self, map_id: str, data: bytes, overwrite: bool = False,
                    max_cells: int = 1_000_000, max_block_samples: int | None = None) -> WallMap:
        """Validate ``data`` as a map file completely, then store it as ``map_id`` atomically.

        The zip and array headers are checked before anything is decompressed
        (:func:`~service.npzcheck.check_map_headers`); then the file is read and every value
        checked (:func:`validate_map`). Nothing is stored unless it can be served.

        Raises
        ------
        MapRejected
            Not a valid map file; ``field`` names the key at fault (nothing is stored).
        MapExists
            ``map_id`` exists and ``overwrite`` is False.
        """
        if self.exists(map_id) and not overwrite:
            raise MapExists(map_id)
        check_map_headers(data, max_cells)
        fd, tmp = tempfile.mkstemp(prefix=f".{map_id}.", suffix=UPLOAD_SUFFIX,
                                   dir=self.directory)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            try:
                wallmap = _read_map(Path(tmp))
            except ValueError as exc:  # the reader's message starts with the path: drop it
                detail = str(exc).replace(f"{tmp}: ", "").replace(tmp, "upload")
                key = _KEY_IN_MESSAGE.search(detail)
                raise MapRejected(key.group(1) if key else "body",
                                  f"not a valid map file: {detail}",
                                  "see docs/formats.md" if key else "a map file (.npz)") from None
            validate_map(wallmap, max_block_samples)
            map_info(map_id, wallmap, len(data), "0" * 64)  # what GET /maps/{id} will serve
            if self.exists(map_id) and not overwrite:
                raise MapExists(map_id)
            os.replace(tmp, self.path(map_id))
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        return wallmap

    def delete(self, map_id: str, users: Callable[[], int]) -> None:
        """Remove the map ``map_id`` unless ``users()`` (sessions on it) is above zero.

        The file is first renamed away, so no new session can load it, then ``users()`` is
        asked; if something uses the map it is renamed back (never over a file uploaded
        meanwhile) and :class:`MapInUse` raised. A kill between the two steps leaves a
        hidden ``.tmp`` file that :meth:`clean_orphans` removes at start.

        Raises
        ------
        MapNotFound
            No map ``map_id``.
        MapInUse
            ``users()`` > 0 (the map is kept).
        """
        aside = self.directory / f".{map_id}.{secrets.token_hex(4)}.deleted.tmp"
        try:
            os.rename(self.path(map_id), aside)
        except FileNotFoundError:
            raise MapNotFound(map_id) from None
        n = users()
        if n > 0:
            try:
                os.link(aside, self.path(map_id))  # no clobbering a newer upload
            except FileExistsError:
                pass
            os.unlink(aside)
            raise MapInUse(map_id, f"{n} live session(s) use map {map_id!r}; delete them "
                           "first")
        os.unlink(aside)
        with self._lock:
            self._digests.pop(map_id, None)
            self._infos.pop(map_id, None)

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


def map_info(map_id: str, m: WallMap, size_bytes: int, sha256: str) -> dict[str, Any]:
    """The :class:`~service.schemas.MapInfo` of a map, validated (``MapRejected`` if the map
    cannot be described by it)."""
    from pydantic import ValidationError

    from service.schemas import MapInfo

    try:
        sonar: dict[str, Any] = json.loads(m.sonar) if m.sonar else {}
    except ValueError:
        sonar = {}
    out = {
        "id": map_id, "shape": m.shape,
        "origin_m": (float(m.origin_m[0]), float(m.origin_m[1])),
        "resolution_m": float(m.resolution_m),
        "extent_m": tuple(float(v) for v in m.extent_m),
        "method": m.method, "params": _jsonable(m.params),
        "provenance": _jsonable(m.provenance), "sonar": sonar, "size_bytes": size_bytes,
        "sha256": sha256,
    }
    try:
        return MapInfo(**out).model_dump()
    except ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(str(p) for p in err["loc"]) or "body"
        raise MapRejected(field, f"{field}: {err['msg']}", "see docs/formats.md") from None


def validate_map(m: WallMap, max_block_samples: int | None = None) -> None:
    """Every value of a map the service would serve; ``MapRejected`` naming the key.

    (:class:`~mapping.wallmap.WallMap` has already checked shapes, finite G and walls.)
    """
    res = m.resolution_m
    if not (math.isfinite(res) and MIN_RESOLUTION_M <= res <= MAX_RESOLUTION_M):
        raise MapRejected("resolution_m", f"resolution_m {res!r} out of range",
                          f"{MIN_RESOLUTION_M:g} <= resolution_m <= {MAX_RESOLUTION_M:g} m")
    ext = m.extent_m
    if not all(math.isfinite(v) and abs(v) <= MAX_COORD_M for v in (*m.origin_m, *ext)):
        raise MapRejected("origin_m", "the map's origin or extent is not finite or lies "
                          f"beyond {MAX_COORD_M:g} m", f"finite, |x|, |y| <= {MAX_COORD_M:g} m "
                          "for every cell")
    if np.abs(m.G).max() > 1e30:
        raise MapRejected("G", "G has values beyond 1e30", "finite, |G| <= 1e30")
    for name in ("params", "provenance"):
        if not isinstance(getattr(m, name), dict):
            raise MapRejected(name, f"{name} must be a JSON object",
                              "JSON text of an object {...}")
    if not (m.method and len(m.method) <= 64 and m.method.isprintable()):
        raise MapRejected("method", "method must be a short printable name", "1..64 characters")
    _validate_sonar(m, max_block_samples)


#: Bounds of the sonar a served map may declare (beyond them a session cannot run).
MAX_DIRECTIONS, MAX_SEQUENCE_LENGTH, MAX_FS_HZ = 1024, 65_535, 1e6


def _validate_sonar(m: WallMap, max_block_samples: int | None) -> None:
    try:
        sonar = map_config(m)
    except (ValueError, TypeError, KeyError) as exc:
        raise MapRejected("sonar", f"sonar is not a valid SonarConfig ({exc})",
                          "JSON of SonarConfig fields (docs/formats.md)") from None
    problems = [
        (sonar.directions > MAX_DIRECTIONS, f"directions <= {MAX_DIRECTIONS}"),
        (sonar.sequence_length > MAX_SEQUENCE_LENGTH,
         f"sequence_length <= {MAX_SEQUENCE_LENGTH}"),
        (sonar.fs_hz > MAX_FS_HZ, f"fs_hz <= {MAX_FS_HZ:g}"),
        (not 100 <= sonar.sound_speed_m_s <= 5000, "100 <= sound_speed_m_s <= 5000"),
        (max_block_samples is not None and sonar.block_samples > max_block_samples,
         f"a block of <= {max_block_samples} samples (one request body)"),
    ]
    for bad, allowed in problems:
        if bad:
            raise MapRejected("sonar", f"sonar outside what the service runs: {allowed}",
                              allowed)


def _jsonable(obj: Any) -> Any:
    """Plain JSON values (numpy scalars/arrays to Python)."""
    return json.loads(json.dumps(obj, default=_default))


def _default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return str(o)
