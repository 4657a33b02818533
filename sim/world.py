# The simulated arena: walls as segments, circular obstacles, seeded placement, world files.
from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from nav.dock import DockShape, in_contact

T = TypeVar("T")

#: Where the built-in worlds live (package data): ``<name>.toml``, selected by ``name``.
WORLDS_DIR = Path(__file__).parent / "worlds"
#: What a world file's name ends in; a world name without one of these is a built-in world.
WORLD_SUFFIXES = (".toml", ".json")


class WorldError(ValueError):
    """A world that cannot be built or a world file that cannot be read; names the field."""


@dataclass(frozen=True)
class Pose:
    """A planar pose in the world frame: metres and radians (counter-clockwise from +x)."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0


@dataclass(frozen=True)
class Segment:
    """A wall from (x1, y1) to (x2, y2)."""

    x1: float
    y1: float
    x2: float
    y2: float


@dataclass(frozen=True)
class Circle:
    """A round obstacle centred at (x, y) with radius ``r``."""

    x: float
    y: float
    r: float


@dataclass(frozen=True)
class World:
    """Static geometry of the arena plus the pose the robot starts at.

    ``segments`` and ``circles`` are also kept as numpy arrays (``(N, 4)`` and ``(M, 3)``)
    for the vectorised ray caster and the collision checks.
    """

    segments: tuple[Segment, ...]
    circles: tuple[Circle, ...]
    start: Pose = Pose()
    #: charging docks, each the robot's pose when docked (their V's arms are in ``segments``)
    docks: tuple[Pose, ...] = ()
    segment_array: np.ndarray = field(init=False, repr=False, compare=False)
    circle_array: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        seg = np.array([(s.x1, s.y1, s.x2, s.y2) for s in self.segments], dtype=float)
        cir = np.array([(c.x, c.y, c.r) for c in self.circles], dtype=float)
        object.__setattr__(self, "segment_array", seg.reshape(-1, 4))
        object.__setattr__(self, "circle_array", cir.reshape(-1, 3))

    def clearance(self, x: float, y: float) -> float:
        """Distance from the point (x, y) to the nearest wall or obstacle surface."""
        return float(min(_segment_distances(self.segment_array, x, y).min(initial=math.inf),
                         _circle_distances(self.circle_array, x, y).min(initial=math.inf)))

    def nearby(self, x: float, y: float,
               within: float) -> tuple[tuple[Circle, ...], tuple[Segment, ...]]:
        """The circles and walls whose surface is closer than ``within`` to (x, y)."""
        near_circles = _circle_distances(self.circle_array, x, y) < within
        near_segments = _segment_distances(self.segment_array, x, y) < within
        return (tuple(c for c, near in zip(self.circles, near_circles, strict=True) if near),
                tuple(s for s, near in zip(self.segments, near_segments, strict=True) if near))

    def to_dict(self) -> dict[str, Any]:
        """The world in the world-file format (see docs/simulator.md)."""
        arms = {arm for dock in self.docks for arm in dock_arms(dock)}
        return {
            "start": {"x": self.start.x, "y": self.start.y, "theta": self.start.theta},
            "walls": [{"from": [s.x1, s.y1], "to": [s.x2, s.y2]} for s in self.segments
                      if s not in arms],
            "circles": [{"center": [c.x, c.y], "radius": c.r} for c in self.circles],
            **({"docks": [{"x": d.x, "y": d.y, "theta": d.theta} for d in self.docks]}
               if self.docks else {}),
        }

    def docked(self, x: float, y: float, theta: float) -> bool:
        """The robot at (x, y, theta) touches a dock's charging contacts."""
        return any(in_contact((x, y, theta), (d.x, d.y, d.theta)) for d in self.docks)


#: the shape of the simulator's docks
DOCK_SHAPE = DockShape()


def dock_arms(dock: Pose) -> tuple[Segment, ...]:
    """The two arms of the V of a dock (its pose: the robot's when docked)."""
    return tuple(Segment(*arm) for arm in DOCK_SHAPE.arms((dock.x, dock.y, dock.theta)))


def _segment_distances(seg: np.ndarray, x: float, y: float) -> np.ndarray:
    ax, ay, bx, by = seg[:, 0], seg[:, 1], seg[:, 2], seg[:, 3]
    ex, ey = bx - ax, by - ay
    length2 = ex * ex + ey * ey
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(length2 > 0, ((x - ax) * ex + (y - ay) * ey) / length2, 0.0)
    u = np.clip(u, 0.0, 1.0)
    return np.asarray(np.hypot(ax + u * ex - x, ay + u * ey - y))


def _circle_distances(cir: np.ndarray, x: float, y: float) -> np.ndarray:
    return np.asarray(np.hypot(cir[:, 0] - x, cir[:, 1] - y) - cir[:, 2])


def arena_walls(width: float, height: float) -> tuple[Segment, ...]:
    """Four walls of a ``width`` x ``height`` rectangle centred on the origin."""
    hx, hy = width / 2.0, height / 2.0
    return (Segment(-hx, -hy, hx, -hy), Segment(hx, -hy, hx, hy),
            Segment(hx, hy, -hx, hy), Segment(-hx, hy, -hx, -hy))


def generated_world(seed: int, *, size: float = 16.0, obstacles: int = 8,
                    radius_min: float = 0.3, radius_max: float = 0.6,
                    start: Pose = Pose(), start_clearance: float = 1.5,
                    wall_margin: float = 0.5, max_tries: int = 10000) -> World:
    """A square arena of side ``size`` with ``obstacles`` circles placed from ``seed``.

    No circle comes within ``start_clearance`` of the start position (so the robot can drive
    away from it), within ``wall_margin`` of a wall, or within ``wall_margin`` of another circle.
    """
    if radius_min <= 0 or radius_max < radius_min:
        raise WorldError(f"obstacle radii must satisfy 0 < min <= max, got {radius_min}, "
                         f"{radius_max}")
    half = size / 2.0
    if abs(start.x) >= half or abs(start.y) >= half:
        raise WorldError(f"start pose ({start.x}, {start.y}) is outside the {size} m arena")
    rng = np.random.Generator(np.random.PCG64(seed))
    placed: list[Circle] = []
    for _ in range(max_tries):
        if len(placed) == obstacles:
            break
        r = float(rng.uniform(radius_min, radius_max))
        limit = half - wall_margin - r
        if limit <= 0:
            raise WorldError(f"obstacle radius {r:.2f} m does not fit the {size} m arena")
        x, y = (float(v) for v in rng.uniform(-limit, limit, size=2))
        if _fits(x, y, r, placed, start, start_clearance, wall_margin):
            placed.append(Circle(round(x, 4), round(y, 4), round(r, 4)))
    if len(placed) < obstacles:
        raise WorldError(f"could not place {obstacles} obstacles in a {size} m arena "
                         f"(placed {len(placed)})")
    return World(arena_walls(size, size), tuple(placed), start)


def _fits(x: float, y: float, r: float, placed: Sequence[Circle], start: Pose,
          start_clearance: float, gap: float) -> bool:
    if math.hypot(x - start.x, y - start.y) - r < start_clearance:
        return False
    return all(math.hypot(x - c.x, y - c.y) - r - c.r >= gap for c in placed)


# -- world files ------------------------------------------------------------------------------

def builtin_worlds() -> tuple[str, ...]:
    """The names of the built-in worlds (``apartment``, ``loop``, ``warehouse``, ...)."""
    return tuple(sorted(path.stem for path in WORLDS_DIR.glob("*.toml")))


def world_path(name: str | Path) -> Path:
    """The file of a world: a path ending in ``.toml`` or ``.json`` as it is, any other
    value the built-in world of that name; an unknown name raises :class:`WorldError`."""
    if isinstance(name, Path) or str(name).lower().endswith(WORLD_SUFFIXES):
        return Path(name)
    if name not in builtin_worlds():
        raise WorldError(f"unknown world {name!r}: a built-in world is one of "
                         f"{', '.join(builtin_worlds())}, a world file ends in .toml or .json")
    return WORLDS_DIR / f"{name}.toml"


def load_world(path: str | Path) -> World:
    """Read a world from a ``.toml`` or ``.json`` file (format in docs/simulator.md), or
    the built-in world of that name (:func:`world_path`)."""
    return load_document(world_path(path), "world file", WorldError, world_from_dict)


def load_document(path: str | Path, what: str, error: type[ValueError],
                  parse: Callable[[Any], T]) -> T:
    """``parse(data)`` of a ``.toml`` or ``.json`` file (``what`` it is, e.g. "world file");
    every problem, the parser's ``error`` too, raises ``error`` naming the file."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(raw)
        elif path.suffix.lower() == ".toml":
            data = tomllib.loads(raw.decode("utf-8"))
        else:
            raise error(f"{path}: {what}s must end in .toml or .json")
    except (json.JSONDecodeError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{path}: not valid {path.suffix[1:].upper()}: {exc}") from None
    try:
        return parse(data)
    except error as exc:
        raise error(f"{path}: {exc}") from None


def finite_number(value: Any, where: str, error: type[ValueError]) -> float:
    """``value`` as a float when it is a finite int or float (not a bool); else ``error``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise error(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise error(f"{where}: must be finite, got {value}")
    return float(value)


def world_from_dict(data: Any) -> World:
    """Build a world from the world-file structure; errors name the offending field."""
    if not isinstance(data, Mapping):
        raise WorldError("the top level must be a table/object")
    _reject_unknown(data, {"arena", "start", "walls", "circles", "docks"}, "")
    walls = list(_arena(data.get("arena")))
    walls += [_wall(item, f"walls[{i}]") for i, item in enumerate(_list(data, "walls"))]
    circles = [_circle(item, f"circles[{i}]") for i, item in enumerate(_list(data, "circles"))]
    if not walls and not circles:
        raise WorldError("the world has no walls and no circles")
    start = _start(data.get("start"))
    docks = [_dock(item, f"docks[{i}]") for i, item in enumerate(_list(data, "docks"))]
    walls += [arm for dock in docks for arm in dock_arms(dock)]
    world = World(tuple(walls), tuple(circles), start, tuple(docks))
    if world.clearance(start.x, start.y) <= 0:
        raise WorldError(f"start: ({start.x}, {start.y}) is inside or on an obstacle")
    return world


def _reject_unknown(table: Mapping[str, Any], allowed: set[str], where: str) -> None:
    for key in table:
        if key not in allowed:
            name = f"{where}.{key}" if where else key
            raise WorldError(f"unknown field {name!r} (expected one of: "
                             f"{', '.join(sorted(allowed))})")


def _list(data: Mapping[str, Any], key: str) -> list[Any]:
    value = data.get(key, [])
    if not isinstance(value, list):
        raise WorldError(f"{key}: expected a list, got {type(value).__name__}")
    return value


def _table(value: Any, where: str, allowed: set[str]) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise WorldError(f"{where}: expected a table/object, got {type(value).__name__}")
    _reject_unknown(value, allowed, where)
    for key in allowed - {"theta"}:
        if key not in value:
            raise WorldError(f"{where}.{key}: missing")
    return value


def _number(value: Any, where: str) -> float:
    return finite_number(value, where, WorldError)


def _point(value: Any, where: str) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        raise WorldError(f"{where}: expected [x, y], got {value!r}")
    return _number(value[0], f"{where}[0]"), _number(value[1], f"{where}[1]")


def _arena(value: Any) -> tuple[Segment, ...]:
    if value is None:
        return ()
    table = _table(value, "arena", {"width", "height"})
    width, height = _number(table["width"], "arena.width"), _number(table["height"], "arena.height")
    if width <= 0 or height <= 0:
        raise WorldError(f"arena: width and height must be > 0, got {width} x {height}")
    return arena_walls(width, height)


def _wall(value: Any, where: str) -> Segment:
    table = _table(value, where, {"from", "to"})
    (x1, y1), (x2, y2) = _point(table["from"], f"{where}.from"), _point(table["to"], f"{where}.to")
    if (x1, y1) == (x2, y2):
        raise WorldError(f"{where}: a wall needs two different end points")
    return Segment(x1, y1, x2, y2)


def _circle(value: Any, where: str) -> Circle:
    table = _table(value, where, {"center", "radius"})
    x, y = _point(table["center"], f"{where}.center")
    r = _number(table["radius"], f"{where}.radius")
    if r <= 0:
        raise WorldError(f"{where}.radius: must be > 0, got {r}")
    return Circle(x, y, r)


def _dock(value: Any, where: str) -> Pose:
    table = _table(value, where, {"x", "y", "theta"})
    if "theta" not in table:
        raise WorldError(f"{where}.theta: missing (the heading of the robot when docked)")
    return Pose(_number(table["x"], f"{where}.x"), _number(table["y"], f"{where}.y"),
                _number(table["theta"], f"{where}.theta"))


def _start(value: Any) -> Pose:
    if value is None:
        return Pose()
    table = _table(value, "start", {"x", "y", "theta"})
    theta = _number(table.get("theta", 0.0), "start.theta")
    return Pose(_number(table["x"], "start.x"), _number(table["y"], "start.y"), theta)
