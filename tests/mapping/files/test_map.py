"""Map file round trip, refusal of damaged files, ROS map_server export."""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

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


# ---- version 2: walls, coverage; reading version 1 ------------------------------------------
def _walls_map() -> WallMap:
    G = np.zeros((40, 60))
    coverage = np.zeros_like(G, dtype=bool)
    coverage[5:35, 5:55] = True
    return WallMap(
        G=G, origin_m=(0.0, 0.0), resolution_m=0.05, method="walls",
        walls_m=np.array([[0.5, 0.5, 2.5, 0.5], [0.5, 1.5, 2.5, 1.5], [0.5, 0.3, 2.5, 0.3]]),
        wall_strength=np.array([1.0, 0.4, 0.4]),
        wall_sigma=np.array([[0.01, 0.002, 0.03], [0.02, 0.004, np.nan], [0.02, 0.004, 0.05]]),
        wall_ambiguous=np.array([False, True, True]), wall_pair=np.array([-1, 2, 1]),
        coverage=coverage)


def test_v2_round_trip_with_walls(tmp_path: Path) -> None:
    wm = _walls_map()
    back = read_map(write_map(tmp_path / "m.npz", wm))
    for name in ("walls_m", "wall_strength", "wall_sigma", "wall_ambiguous", "wall_pair",
                 "coverage"):
        np.testing.assert_array_equal(getattr(back, name), getattr(wm, name))
        assert getattr(back, name).dtype == getattr(wm, name).dtype
    with np.load(tmp_path / "m.npz") as npz:
        assert str(npz["format"]) == "omnisonar-map-2"


@pytest.mark.parametrize("key", ["walls_m", "wall_strength", "wall_sigma", "wall_ambiguous",
                                 "wall_pair", "coverage"])
def test_v2_checksum_covers_new_keys(tmp_path: Path, key: str) -> None:
    p = write_map(tmp_path / "m.npz", _walls_map())
    with np.load(p) as npz:
        arrays = {k: npz[k] for k in npz.files}
    a = arrays[key].copy()
    a.flat[0] = ~a.flat[0] if a.dtype == bool else a.flat[0] + 1
    arrays[key] = a
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(ValueError, match="checksum mismatch"):
        read_map(tmp_path / "bad.npz")
    del arrays[key]
    np.savez(tmp_path / "gone.npz", **arrays)
    with pytest.raises(ValueError, match=f"missing key.*{key}"):
        read_map(tmp_path / "gone.npz")


def _v1_checksum(arrays: dict[str, Any]) -> str:
    """The omnisonar-map-1 checksum, written out independently of the reader."""
    import hashlib

    h = hashlib.sha256(b"omnisonar-map-1")
    for key in ("G", "origin_m", "resolution_m", "sonar", "method", "params", "provenance"):
        a = arrays[key]
        data = str(a).encode() if a.dtype.kind == "U" else np.ascontiguousarray(a).tobytes()
        h.update(f"|{key}|{a.dtype.str}|{a.shape}|".encode() + data)
    return h.hexdigest()


def test_reads_v1_file(tmp_path: Path) -> None:
    """A file with the old key set (as omnisonar-map-1 wrote it) reads with no walls and every
    cell observed; a v1 file whose G was altered is still refused."""
    G = np.random.default_rng(4).random((5, 8))
    arrays: dict[str, Any] = {"format": np.array("omnisonar-map-1"), "G": G,
              "origin_m": np.array([0.5, -1.0]), "resolution_m": np.float64(0.05),
              "sonar": np.array("{}"), "method": np.array("paper"),
              "params": np.array('{"radius_m": 6.0}'), "provenance": np.array("{}")}
    arrays["checksum"] = np.array(_v1_checksum(arrays))
    np.savez(tmp_path / "v1.npz", **arrays)
    wm = read_map(tmp_path / "v1.npz")
    np.testing.assert_array_equal(wm.G, G)
    assert wm.origin_m == (0.5, -1.0) and wm.params == {"radius_m": 6.0}
    assert wm.walls_m.shape == (0, 4) and wm.n_walls == 0
    assert wm.coverage.shape == G.shape and wm.coverage.all()
    arrays["G"] = G + 1e-9
    np.savez(tmp_path / "v1bad.npz", **arrays)
    with pytest.raises(ValueError, match="checksum mismatch"):
        read_map(tmp_path / "v1bad.npz")


def test_ros_export_from_walls(tmp_path: Path) -> None:
    """With walls the PGM is the wall raster: occupied on the wall lines (one cell wide), free
    in coverage, unknown outside; G plays no part."""
    wm = _walls_map()
    img = read_pgm(write_ros_map(tmp_path / "w.pgm", wm)[0])[::-1, :]  # row 0 = smallest y
    assert img.shape == wm.shape
    # the wall y = 0.5 m from x = 0.5 to 2.5 m is row 10, columns 10..50, one cell wide
    assert np.all(img[10, 10:51] == 0) and img[10, 9] != 0 and img[10, 51] != 0
    assert np.all(img[9, 10:51] != 0) and np.all(img[11, 10:51] != 0)
    assert set(np.unique(img)) == {0, 205, 254}
    assert img[20, 20] == 254 and img[0, 0] == 205  # free inside coverage, unknown outside
    # map_server reads 254 as free and 205 as unknown with the thresholds of the YAML
    assert (255 - 254) / 255 < 0.196 < (255 - 205) / 255 < 0.65


def test_geojson_of_walls(tmp_path: Path) -> None:
    import json

    from mapping.files import write_geojson

    wm = _walls_map()
    doc = json.loads(write_geojson(tmp_path / "w.geojson", wm).read_text())
    assert doc["type"] == "FeatureCollection" and doc["units"] == "m" and doc["frame"] == "map"
    assert len(doc["features"]) == 3
    f0, f1 = doc["features"][0], doc["features"][1]
    assert f0["geometry"] == {"type": "LineString", "coordinates": [[0.5, 0.5], [2.5, 0.5]]}
    assert f0["properties"]["pair"] is None and f0["properties"]["ambiguous"] is False
    assert f0["properties"]["sigma"] == {"normal_offset_m": 0.01, "angle_rad": 0.002,
                                         "endpoint_m": 0.03}
    assert f1["properties"]["pair"] == 2 and f1["properties"]["ambiguous"] is True
    assert f1["properties"]["sigma"]["endpoint_m"] is None  # NaN: not estimated
    assert f1["properties"]["strength"] == 0.4
    empty = json.loads(write_geojson(tmp_path / "e.geojson", _map()).read_text())
    assert empty["features"] == []
