# Maps as files in the map_server format (Nav2, slam_toolbox): NAME.yaml beside NAME.pgm.
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from daemon.files import list_regular, read_head, read_regular, write_atomically

#: the thresholds a saved YAML carries; grey 205 (unknown) reads as occupancy 50/255 = 0.196,
#: which a free threshold of 0.196 keeps unknown (a reader tests ``occ < free_thresh``)
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196
FREE_GREY, UNKNOWN_GREY, OCCUPIED_GREY = 254, 205, 0
#: cells below this occupancy (percent) are saved as free
SAVE_FREE_BELOW = 25
YAML_KEYS = {"image", "mode", "resolution", "origin", "negate", "occupied_thresh",
             "free_thresh"}
REQUIRED_KEYS = ("image", "resolution", "origin")
MODES = ("trinary", "scale", "raw")
#: the largest image a map file may hold (a 500 m square at 0.05 m)
MAX_CELLS = 100_000_000
#: the largest map YAML read, and how much of an image is read for its header
MAX_YAML_BYTES = 65536
HEADER_BYTES = 512

Int8Grid = npt.NDArray[np.int8]


class MapFileError(ValueError):
    """A map file that cannot be read or written; the text names the file and the problem."""


@dataclass(frozen=True)
class MapData:
    """A grid as nav_msgs/OccupancyGrid holds it: int8 cells, -1 unknown, 0..100 occupied,
    row 0 at ``origin_y`` (y up), ``resolution`` metres per cell."""

    occupancy: Int8Grid
    resolution: float
    origin_x: float
    origin_y: float

    @property
    def height(self) -> int:
        return int(self.occupancy.shape[0])

    @property
    def width(self) -> int:
        return int(self.occupancy.shape[1])


# -- writing ----------------------------------------------------------------------------------

def save_map(directory: Path, name: str, grid: MapData,
             max_total_bytes: int | None = None) -> tuple[Path, Path]:
    """Write NAME.pgm and NAME.yaml (trinary, as map_saver does); each file is written to a
    temporary name first, so a reader never sees half a map. With ``max_total_bytes``, the
    maps directory's saved maps (this one's old files not counted) stay within it, else
    :class:`~daemon.files.FileRefused`. Returns both paths."""
    image, text = pgm_bytes(grid.occupancy), yaml_text(f"{name}.pgm", grid).encode()
    room = None
    if max_total_bytes is not None:
        replaced = {f"{name}.pgm", f"{name}.yaml"}
        used = sum(size for file, size, _ in list_regular(directory, is_map_file).files
                   if file not in replaced)
        room = max_total_bytes - used - len(text)
    limit = MAX_CELLS + 4096
    pgm = write_atomically(directory, f"{name}.pgm", image, max_bytes=limit, room=room)
    yml = write_atomically(directory, f"{name}.yaml", text, max_bytes=MAX_YAML_BYTES)
    return pgm, yml


def is_map_file(name: str) -> bool:
    return name.endswith((".yaml", ".pgm")) and not name.startswith(".")


def pgm_bytes(occupancy: Int8Grid) -> bytes:
    """The grid as a binary PGM (P5), top row first: free 254, unknown 205, occupied 0."""
    grey = np.full(occupancy.shape, UNKNOWN_GREY, dtype=np.uint8)
    grey[(occupancy >= 0) & (occupancy < SAVE_FREE_BELOW)] = FREE_GREY
    grey[occupancy >= OCCUPIED_THRESH * 100] = OCCUPIED_GREY
    height, width = occupancy.shape
    header = f"P5\n# arbiterd map\n{width} {height}\n255\n".encode()
    return header + np.ascontiguousarray(grey[::-1]).tobytes()


def yaml_text(image: str, grid: MapData) -> str:
    return yaml.safe_dump({
        "image": image, "mode": "trinary", "resolution": float(grid.resolution),
        "origin": [float(grid.origin_x), float(grid.origin_y), 0.0], "negate": 0,
        "occupied_thresh": OCCUPIED_THRESH, "free_thresh": FREE_THRESH,
    }, sort_keys=False)


# -- reading ----------------------------------------------------------------------------------

def load_map(yaml_path: Path, max_cells: int = MAX_CELLS) -> MapData:
    """Read a map_server YAML and the image it names (PGM, P5 or P2, 8 bit) beside it; an
    image of more than ``max_cells`` cells is refused from its header, before it is read."""
    meta = read_yaml(yaml_path)
    image = Path(meta["image"])
    if image.is_absolute() or image.name != meta["image"]:
        raise MapFileError(f"{yaml_path}: image: expected a file name beside the YAML, got "
                           f"{meta['image']!r}")
    grey = read_pgm(yaml_path.parent / image, max_cells)
    occupancy = occupancy_of(grey, meta)
    origin = meta["origin"]
    return MapData(occupancy, meta["resolution"], origin[0], origin[1])


def read_yaml(path: Path) -> dict[str, Any]:
    """The YAML's keys, checked: every problem names the file and the key."""
    try:
        text = read_regular(path.parent, path.name, MAX_YAML_BYTES).decode("utf-8")
    except FileNotFoundError:
        raise MapFileError(f"{path}: no such map file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MapFileError(f"{path}: cannot read: {exc}") from None
    try:
        meta = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise MapFileError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(meta, dict):
        raise MapFileError(f"{path}: expected the map_server keys (image, resolution, "
                           "origin, ...), got no mapping")
    _check_keys(path, meta)
    return _checked_values(path, meta)


def _check_keys(path: Path, meta: dict[str, Any]) -> None:
    unknown = sorted(str(key) for key in meta if key not in YAML_KEYS)
    if unknown:
        raise MapFileError(f"{path}: unknown key {unknown[0]!r} (a map_server YAML has "
                           f"{', '.join(sorted(YAML_KEYS))})")
    missing = [key for key in REQUIRED_KEYS if key not in meta]
    if missing:
        raise MapFileError(f"{path}: missing key {missing[0]!r}")


def _checked_values(path: Path, meta: dict[str, Any]) -> dict[str, Any]:
    def number(key: str, default: float, low: float, high: float) -> float:
        value = meta.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int | float) or \
                not math.isfinite(value) or not low <= value <= high:
            raise MapFileError(f"{path}: {key}: expected a number in [{low:g}, {high:g}], "
                               f"got {value!r}")
        return float(value)

    checked = {"image": meta["image"], "resolution": number("resolution", 0.05, 1e-4, 100.0),
               "negate": int(number("negate", 0, 0, 1)),
               "occupied_thresh": number("occupied_thresh", OCCUPIED_THRESH, 0.0, 1.0),
               "free_thresh": number("free_thresh", FREE_THRESH, 0.0, 1.0),
               "mode": meta.get("mode", "trinary"), "origin": meta["origin"]}
    if not isinstance(checked["image"], str) or not checked["image"]:
        raise MapFileError(f"{path}: image: expected the image file's name")
    if checked["mode"] not in MODES:
        raise MapFileError(f"{path}: mode: expected one of {', '.join(MODES)}, got "
                           f"{checked['mode']!r}")
    origin = checked["origin"]
    if not isinstance(origin, list) or len(origin) != 3 or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in origin):
        raise MapFileError(f"{path}: origin: expected [x, y, yaw] in metres and radians, "
                           f"got {origin!r}")
    if origin[2] != 0:
        raise MapFileError(f"{path}: origin: a rotated map (yaw {origin[2]}) is not supported; "
                           "save it with yaw 0")
    checked["origin"] = [float(v) for v in origin]
    return checked


_PGM_HEADER = re.compile(rb"(P[25])\s+(?:#[^\n]*\n\s*)*(\d+)\s+(?:#[^\n]*\n\s*)*(\d+)\s+"
                         rb"(?:#[^\n]*\n\s*)*(\d+)\s")


def read_pgm(path: Path, max_cells: int = MAX_CELLS) -> npt.NDArray[np.uint8]:
    """An 8-bit PGM image, top row first; errors name the file and the byte offset. The size
    is checked from the header before the image is read: at most ``max_cells`` cells."""
    kind, width, height, start = pgm_header(path, max_cells)
    limit = start + width * height * (4 if kind == b"P2" else 1) + 4096
    data = _read(path, limit)
    if kind == b"P2":  # the header was matched with CRLF as LF
        return _plain_pgm(path, data.replace(b"\r\n", b"\n")[start:], width, height)
    body = data[start:]
    expected = width * height
    if len(body) < expected:
        raise MapFileError(f"{path}: truncated: {width} x {height} cells need {expected} "
                           f"bytes after the header (byte {start}), found {len(body)}")
    return np.frombuffer(body[:expected], dtype=np.uint8).reshape(height, width)


def pgm_header(path: Path, max_cells: int = MAX_CELLS) -> tuple[bytes, int, int, int]:
    """A PGM's kind (P5, P2), width, height and where its data starts, from its first bytes
    only; a map of more than ``max_cells`` cells is refused here."""
    try:
        head = read_head(path.parent, path.name, HEADER_BYTES)
    except FileNotFoundError:
        raise MapFileError(f"{path}: the map's image file is missing") from None
    except OSError as exc:
        raise MapFileError(f"{path}: cannot read: {exc}") from None
    header = _PGM_HEADER.match(head.replace(b"\r\n", b"\n") if head[:2] == b"P2" else head)
    if header is None:
        raise MapFileError(f"{path}: not a PGM image (byte 0: expected 'P5' or 'P2' and a "
                           "width, height and maximum value); arbiterd reads PGM maps")
    kind, width, height, maxval = header[1], int(header[2]), int(header[3]), int(header[4])
    if not 0 < maxval < 256:
        raise MapFileError(f"{path}: maximum value {maxval}: expected an 8-bit image")
    if not 0 < width * height <= max_cells:
        raise MapFileError(f"{path}: {width} x {height} = {width * height} cells: at most "
                           f"{max_cells} are loaded ([mapping] max_size_m / resolution, "
                           "squared)")
    return kind, width, height, header.end()


def _read(path: Path, limit: int) -> bytes:
    try:
        return read_regular(path.parent, path.name, limit)
    except FileNotFoundError:
        raise MapFileError(f"{path}: the map's image file is missing") from None
    except OSError as exc:
        raise MapFileError(f"{path}: cannot read: {exc}") from None


def _plain_pgm(path: Path, body: bytes, width: int, height: int) -> npt.NDArray[np.uint8]:
    values = body.split()
    if len(values) < width * height:
        raise MapFileError(f"{path}: truncated: {width * height} values expected, found "
                           f"{len(values)}")
    try:
        return np.array(values[:width * height], dtype=np.uint8).reshape(height, width)
    except ValueError:
        raise MapFileError(f"{path}: a value of the plain PGM is not a number") from None


def occupancy_of(grey: npt.NDArray[np.uint8], meta: dict[str, Any]) -> Int8Grid:
    """Grey levels to occupancy as map_server interprets them (``mode``, ``negate``, the
    thresholds); row 0 becomes the bottom of the map."""
    if meta["mode"] == "raw":
        return grey[::-1].astype(np.int16).clip(-1, 100).astype(np.int8)
    p = grey.astype(np.float64) / 255.0
    occupied = p if meta["negate"] else 1.0 - p
    out = np.full(grey.shape, -1, dtype=np.int8)
    if meta["mode"] == "trinary":
        out[occupied > meta["occupied_thresh"]] = 100
        out[occupied < meta["free_thresh"]] = 0
    else:  # scale: between the thresholds, a probability
        between = (occupied >= meta["free_thresh"]) & (occupied <= meta["occupied_thresh"])
        span = max(meta["occupied_thresh"] - meta["free_thresh"], 1e-9)
        out[between] = np.rint(99 * (occupied[between] - meta["free_thresh"]) / span)
        out[occupied > meta["occupied_thresh"]] = 100
        out[occupied < meta["free_thresh"]] = 0
    return np.ascontiguousarray(out[::-1])


def saved_maps(directory: Path) -> list[dict[str, Any]]:
    """The maps in ``directory``: name, size and the YAML's resolution, newest first; each
    read no further than its YAML and its image's header (bounded work per listing)."""
    out = []
    listing = list_regular(directory, lambda name: name.endswith(".yaml") and
                           not name.startswith("."))
    for name, _, modified in listing.files:
        yml = directory / name
        entry: dict[str, Any] = {"name": yml.stem, "modified": modified}
        try:
            meta = read_yaml(yml)
            _, width, height, _ = pgm_header(yml.parent / Path(meta["image"]).name)
            entry.update(resolution=meta["resolution"], width=width, height=height)
        except MapFileError as exc:
            entry["error"] = str(exc)
        out.append(entry)
    return sorted(out, key=lambda e: -e["modified"])
