"""The one atomic writer: content, no temporary left behind, permissions, failure cleanup."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from mapping.files import atomic_savez, atomic_write, atomic_write_bytes


def test_bytes_roundtrip_and_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "a.bin"
    atomic_write_bytes(target, b"abc")
    atomic_write_bytes(target, b"xyz", fsync=False)
    assert target.read_bytes() == b"xyz"
    assert [p.name for p in target.parent.iterdir()] == ["a.bin"]


def test_savez_roundtrip(tmp_path: Path) -> None:
    target = tmp_path / "a.npz"
    atomic_savez(target, {"x": np.arange(3)})
    with np.load(target) as npz:
        np.testing.assert_array_equal(npz["x"], np.arange(3))


def test_failed_write_keeps_old_file_and_removes_temporary(tmp_path: Path) -> None:
    target = tmp_path / "a.bin"
    target.write_bytes(b"old")

    def boom(fh: object) -> None:
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_write(target, boom)
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.bin"]


def test_permissions_private_or_umask(tmp_path: Path) -> None:
    mask = os.umask(0o022)
    try:
        atomic_write_bytes(tmp_path / "p.bin", b"1")
        atomic_write(tmp_path / "u.bin", lambda fh: fh.write(b"1"), private=False)
        (tmp_path / "plain.bin").write_bytes(b"1")
    finally:
        os.umask(mask)
    assert (tmp_path / "p.bin").stat().st_mode & 0o777 == 0o600
    plain = (tmp_path / "plain.bin").stat().st_mode & 0o777
    assert (tmp_path / "u.bin").stat().st_mode & 0o777 == plain == 0o644
