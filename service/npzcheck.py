"""Checks of an uploaded map file (``.npz``) from its zip and ``.npy`` headers alone.

An ``.npz`` is a zip of ``.npy`` members; each member's zip entry declares its uncompressed
size and each ``.npy`` header declares its dtype and shape. :func:`check_map_headers` reads
only those (the zip's central directory and the first bytes of each member), so a
decompression bomb or a map too large to serve is refused before anything is decompressed.
Python's zip reader never inflates a member beyond its declared size, so the declared sizes
checked here bound the memory of the full read that follows.
"""

from __future__ import annotations

import io
import math
import zipfile
from dataclasses import dataclass
from typing import IO

import numpy as np

#: Longest text member (sonar, params, provenance, ...), in characters.
MAX_TEXT_CHARS = 256 * 1024
#: Most fitted walls a map may carry.
MAX_WALLS = 100_000

_TEXT_KEYS = ("format", "sonar", "method", "params", "provenance", "checksum")
_WALL_KEYS = {"walls_m": (4,), "wall_strength": (), "wall_sigma": (3,),
              "wall_ambiguous": (), "wall_pair": ()}
_KNOWN = {"G", "origin_m", "resolution_m", "coverage", *_TEXT_KEYS, *_WALL_KEYS}


class MapRejected(ValueError):
    """An uploaded map the service will not store: ``field`` is at fault, ``allowed`` says
    what would pass."""

    def __init__(self, field: str, detail: str, allowed: str | None = None) -> None:
        super().__init__(detail)
        self.field, self.allowed = field, allowed


@dataclass(frozen=True)
class Member:
    """One ``.npy`` member as its header declares it."""

    key: str
    dtype: np.dtype
    shape: tuple[int, ...]
    file_size: int


def check_map_headers(data: bytes, max_cells: int) -> dict[str, Member]:
    """Validate the zip and ``.npy`` headers of a map upload; nothing is decompressed.

    Parameters
    ----------
    data : bytes
        The uploaded file.
    max_cells : int
        Largest ``G`` (ny * nx) accepted.

    Returns
    -------
    dict
        The members by key.

    Raises
    ------
    MapRejected
        Not a zip, an unknown or duplicate member, a compression other than deflate, a dtype
        or shape the format does not allow, a ``G`` over ``max_cells``, or declared sizes
        that disagree with the headers.
    """
    try:
        zf = zipfile.ZipFile(io.BytesIO(data))
    except (zipfile.BadZipFile, ValueError, OSError):
        raise MapRejected("body", "not a map file: not a zip (.npz) archive",
                          "a map file (.npz)") from None
    with zf:
        infos = zf.infolist()
        if len(infos) > len(_KNOWN):
            raise MapRejected("body", f"{len(infos)} members; a map file has at most "
                              f"{len(_KNOWN)}", "the keys of docs/formats.md")
        members = {}
        for info in infos:
            m = _member(zf, info)
            if m.key in members:
                raise MapRejected(m.key, f"member {m.key!r} appears twice", "once")
            members[m.key] = m
    _check_shapes(members, max_cells)
    return members


def _member(zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> Member:
    key = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
    if key not in _KNOWN:
        raise MapRejected("body", f"unknown member {info.filename[:80]!r}",
                          "the keys of docs/formats.md")
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise MapRejected(key, "member compressed with an unsupported method",
                          "stored or deflate (numpy.savez / savez_compressed)")
    try:
        with zf.open(info) as fh:
            dtype, shape, offset = _npy_header(fh)
    except (ValueError, zipfile.BadZipFile, OSError, EOFError) as exc:
        raise MapRejected(key, f"unreadable .npy header ({_short(exc)})",
                          "a .npy array") from None
    if dtype.hasobject or dtype.kind not in "biufU":
        raise MapRejected(key, f"dtype {dtype.str} not allowed", "numbers or text")
    n = math.prod(shape)
    if n < 0 or info.file_size != offset + n * dtype.itemsize:
        raise MapRejected(key, "declared size disagrees with the array header",
                          "a consistent .npy member")
    return Member(key, dtype, shape, info.file_size)


def _npy_header(fh: IO[bytes]) -> tuple[np.dtype, tuple[int, ...], int]:
    fmt = np.lib.format
    version = fmt.read_magic(fh)
    if version == (1, 0):
        shape, _fortran, dtype = fmt.read_array_header_1_0(fh, max_header_size=10_000)
    elif version == (2, 0):
        shape, _fortran, dtype = fmt.read_array_header_2_0(fh, max_header_size=10_000)
    else:
        raise ValueError(f".npy version {version}")
    return np.dtype(dtype), tuple(int(d) for d in shape), int(fh.tell())


def _short(exc: BaseException) -> str:
    return str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__


def _check_shapes(members: dict[str, Member], max_cells: int) -> None:
    for key in ("format", "G", "origin_m", "resolution_m"):
        if key not in members:
            raise MapRejected(key, f"missing key {key!r}", "the keys of docs/formats.md")
    for key in _TEXT_KEYS:
        if key in members:
            _expect(members[key], "U", (), f"text of <= {MAX_TEXT_CHARS} characters")
            if members[key].dtype.itemsize > 4 * MAX_TEXT_CHARS:
                raise MapRejected(key, f"{key} is longer than {MAX_TEXT_CHARS} characters",
                                  f"<= {MAX_TEXT_CHARS} characters")
    g = members["G"]
    if g.dtype.kind != "f" or len(g.shape) != 2 or min(g.shape) < 1:
        raise MapRejected("G", f"G must be a non-empty 2-D float array, got {g.dtype.str} "
                          f"{g.shape}", "float (ny, nx)")
    cells = g.shape[0] * g.shape[1]
    if cells > max_cells:
        raise MapRejected("G", f"G has {cells} cells {g.shape}", f"<= {max_cells} cells "
                          "(OMNISONAR_MAX_MAP_CELLS)")
    _expect(members["origin_m"], "f", (2,), "2 floats (x, y) in metres")
    _expect(members["resolution_m"], "f", (), "one float, metres (a scalar)")
    if "coverage" in members:
        _expect(members["coverage"], "b", g.shape, f"bool of G's shape {g.shape}")
    _check_walls(members)


def _check_walls(members: dict[str, Member]) -> None:
    n = None
    for key, tail in _WALL_KEYS.items():
        if key not in members:
            continue
        m = members[key]
        if len(m.shape) != 1 + len(tail) or m.shape[1:] != tail:
            raise MapRejected(key, f"{key} has shape {m.shape}", f"(n, {tail})")
        if n is None:
            n = m.shape[0]
        if m.shape[0] != n or n > MAX_WALLS:
            raise MapRejected(key, f"{key} has {m.shape[0]} rows", f"one per wall, <= "
                              f"{MAX_WALLS}")
        if m.dtype.kind not in {"wall_ambiguous": "b", "wall_pair": "iu"}.get(key, "f"):
            raise MapRejected(key, f"{key} has dtype {m.dtype.str}", "see docs/formats.md")


def _expect(m: Member, kinds: str, shape: tuple[int, ...], allowed: str) -> None:
    if m.dtype.kind not in kinds or m.shape != shape:
        raise MapRejected(m.key, f"{m.key} must be {allowed}, got {m.dtype.str} {m.shape}",
                          allowed)
