"""Map file round trip, refusal of damaged files, ROS map_server export."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from mapping.files import read_map, read_pgm, write_map, write_ros_map
from mapping.wallmap import WallMap


def _map() -> WallMap:
    rng = np.random.default_rng(3)
    return WallMap(G=rng.random((7, 9)), origin_m=(-1.25, 2.5), resolution_m=0.05,
                   sonar='{"repetitions": 10}', method="paper",
                   params={"radius_m": 6.0, "literal": False},
                   provenance={"runs": [{"path": "a.npz", "sha256": "00"}]})


def test_round_trip(tmp_path: Path) -> None:
    wm = _map()
    p = write_map(tmp_path / "m.npz", wm)
    back = read_map(p)
    np.testing.assert_array_equal(back.G, wm.G)
    assert back.origin_m == wm.origin_m and back.resolution_m == wm.resolution_m
    assert (back.sonar, back.method, back.params, back.provenance) == (
        wm.sonar, wm.method, wm.params, wm.provenance)
    assert not list(tmp_path.glob(".*tmp"))


def test_truncated_file_refused(tmp_path: Path) -> None:
    p = write_map(tmp_path / "m.npz", _map())
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="not a readable"):
        read_map(p)


def test_altered_file_refused(tmp_path: Path) -> None:
    wm = _map()
    p = write_map(tmp_path / "m.npz", wm)
    with np.load(p) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["G"] = arrays["G"].copy()
    arrays["G"][3, 4] += 1e-9
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match="checksum mismatch"):
        read_map(tmp_path / "bad.npz")
    arrays = {k: v for k, v in arrays.items() if k != "checksum"}
    np.savez(tmp_path / "nock.npz", **arrays)
    with pytest.raises(ValueError, match="missing key"):
        read_map(tmp_path / "nock.npz")
    arrays["format"] = np.array("omnisonar-run-1")
    np.savez(tmp_path / "run.npz", **arrays)
    with pytest.raises(ValueError, match="format"):
        read_map(tmp_path / "run.npz")


def test_flipped_byte_in_zip_refused(tmp_path: Path) -> None:
    p = write_map(tmp_path / "m.npz", _map())
    with zipfile.ZipFile(p) as z:
        assert "G.npy" in z.namelist()
    data = bytearray(p.read_bytes())
    i = data.find(b"\x93NUMPY", 0) + 200  # inside the first array's payload
    data[i] ^= 0xFF
    p.write_bytes(bytes(data))
    with pytest.raises(ValueError):
        read_map(p)


def test_ros_export(tmp_path: Path) -> None:
    G = np.zeros((4, 6))
    G[0, 0] = 1.0  # lower-left cell: strong
    wm = WallMap(G=G, origin_m=(1.0, 2.0), resolution_m=0.05)
    pgm, yaml = write_ros_map(tmp_path / "map.pgm", wm)
    img = read_pgm(pgm)
    assert img.shape == (4, 6)
    assert img[-1, 0] == 0 and img[0, 0] == 255  # first PGM row is the top of the map
    text = yaml.read_text()
    assert "image: map.pgm" in text and "resolution: 0.050000" in text
    assert "origin: [0.975000, 1.975000, 0.0]" in text and "negate: 0" in text
    with pytest.raises(ValueError, match="pgm_path"):
        write_ros_map(tmp_path / "map.png", wm)
