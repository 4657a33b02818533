# Maps as map_server files: what arbiterd writes, an independent reader reads; bad files named.
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from daemon.components.mapping.mapfile import MapData, MapFileError, load_map, save_map, saved_maps


def sample_grid() -> MapData:
    occupancy = np.full((30, 40), -1, dtype=np.int8)
    occupancy[5:25, 5:35] = 0          # a free room
    occupancy[5, 5:35] = 100           # its bottom wall (row 5, y = origin + 5 cells)
    occupancy[24, 5:35] = 100          # its top wall
    occupancy[10, 20] = 40             # a cell the mapper is unsure of: unknown in trinary
    return MapData(occupancy, 0.05, -1.0, -0.75)


def independent_read(yaml_path: Path) -> tuple[dict[str, object], np.ndarray]:
    """A map_server-format reader written here from the format's description, not from
    arbiterd's: YAML keys, a binary PGM with the top row first, occupancy per ROS's rule
    p = (255 - grey) / 255, occupied above occupied_thresh, free below free_thresh."""
    meta = yaml.safe_load(yaml_path.read_text())
    data = (yaml_path.parent / meta["image"]).read_bytes()
    fields = data.split(maxsplit=4) if not data.split(b"\n")[1].startswith(b"#") else \
        [data.split(b"\n")[0], *data.split(b"\n", 2)[2].split(maxsplit=3)]
    magic, width, height, maxval, pixels = fields
    assert magic == b"P5" and int(maxval) == 255
    grey = np.frombuffer(pixels[:int(width) * int(height)], np.uint8).reshape(
        int(height), int(width))
    p = (255 - grey.astype(float)) / 255
    grid = np.full(grey.shape, -1, dtype=np.int8)
    grid[p > meta["occupied_thresh"]] = 100
    grid[p < meta["free_thresh"]] = 0
    return meta, grid[::-1]


def test_a_saved_map_reads_back_in_an_independent_reader(tmp_path: Path) -> None:
    grid = sample_grid()
    pgm, yml = save_map(tmp_path, "room", grid)
    meta, read = independent_read(yml)
    assert meta["image"] == pgm.name and meta["resolution"] == 0.05
    assert meta["origin"] == [-1.0, -0.75, 0.0] and meta["negate"] == 0
    expected = np.where(grid.occupancy == 40, -1, grid.occupancy)
    assert np.array_equal(read, expected)


def test_load_map_round_trips_and_lists(tmp_path: Path) -> None:
    grid = sample_grid()
    save_map(tmp_path, "room", grid)
    loaded = load_map(tmp_path / "room.yaml")
    assert (loaded.resolution, loaded.origin_x, loaded.origin_y) == (0.05, -1.0, -0.75)
    assert np.array_equal(loaded.occupancy, np.where(grid.occupancy == 40, -1, grid.occupancy))
    (entry,) = saved_maps(tmp_path)
    assert (entry["name"], entry["width"], entry["height"]) == ("room", 40, 30)
    assert not list(tmp_path.glob(".*partial"))


def write_map(tmp_path: Path, yaml_text: str, pgm: bytes | None = None) -> Path:
    if pgm is None:
        pgm = b"P5\n4 2\n255\n" + bytes([254, 0, 205, 254, 254, 254, 0, 0])
    (tmp_path / "m.pgm").write_bytes(pgm)
    path = tmp_path / "m.yaml"
    path.write_text(yaml_text)
    return path


GOOD = "image: m.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\n" \
       "occupied_thresh: 0.65\nfree_thresh: 0.196\nnegate: 0\n"


def test_a_plain_map_loads(tmp_path: Path) -> None:
    grid = load_map(write_map(tmp_path, GOOD))
    assert grid.occupancy.tolist() == [[0, 0, 100, 100], [0, 100, -1, 0]]


@pytest.mark.parametrize(("yaml_text", "pgm", "problem"), [
    (GOOD.replace("resolution", "resolutoin"), None, "unknown key 'resolutoin'"),
    (GOOD.replace("image: m.pgm\n", ""), None, "missing key 'image'"),
    (GOOD.replace("0.05", "-1"), None, "resolution: expected a number"),
    (GOOD.replace("[0.0, 0.0, 0.0]", "[0.0, 0.0]"), None, "origin: expected [x, y, yaw]"),
    (GOOD.replace("[0.0, 0.0, 0.0]", "[0.0, 0.0, 0.5]"), None, "rotated map"),
    ("image: [", None, "not valid YAML"),
    ("just text", None, "got no mapping"),
    (GOOD, b"P5\n4 2\n255\n" + bytes(3), "truncated: 4 x 2 cells need 8 bytes"),
    (GOOD, b"\x89PNG\r\n\x1a\n....", "not a PGM image (byte 0"),
    (GOOD, b"P5\n4 2\n65535\n" + bytes(16), "expected an 8-bit image"),
    (GOOD.replace("m.pgm", "gone.pgm"), None, "image file is missing"),
])
def test_bad_map_files_are_named(tmp_path: Path, yaml_text: str, pgm: bytes | None,
                                 problem: str) -> None:
    path = write_map(tmp_path, yaml_text, pgm)
    with pytest.raises(MapFileError) as error:
        load_map(path)
    assert problem in str(error.value)
    assert str(tmp_path) in str(error.value)


def test_a_missing_map_is_named(tmp_path: Path) -> None:
    with pytest.raises(MapFileError, match="no such map file"):
        load_map(tmp_path / "nothing.yaml")
