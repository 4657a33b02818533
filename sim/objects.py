# Graspable objects: small cylinders the lidar sees, held by a closing gripper, carried, released.
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: the default object: a cylinder 45 mm across (the gripper opens 70 mm: two fingers of 35 mm)
OBJECT_RADIUS = 0.0225
#: the tool point must be this near the object's centre (horizontally) when the fingers close
GRASP_TOLERANCE = 0.04
#: how tall an object stands (m; the camera sees it, the planar world does not need it)
OBJECT_HEIGHT = 0.12
#: the colours an object may have, as the simulated camera paints them (RGB)
OBJECT_COLORS: dict[str, tuple[int, int, int]] = {
    "red": (210, 30, 30), "green": (30, 170, 50), "blue": (30, 70, 210),
    "yellow": (225, 200, 20), "magenta": (200, 40, 190), "cyan": (20, 190, 200),
}


@dataclass(frozen=True)
class Tool:
    """Where the arm's tool point is in base_link (x forward, y left, m; the height is not
    modelled: the world is planar) and the gripper's opening (each finger's travel, m)."""

    x: float
    y: float
    opening: float


@dataclass
class SimObject:
    """One object: its true centre in the world (m), its radius, and whether it is held."""

    x: float
    y: float
    radius: float = OBJECT_RADIUS
    held: bool = False
    #: its colour, a name of :data:`OBJECT_COLORS`
    color: str = "red"
    #: the robot's footprint touched it while it stood on the floor (a collision)
    contacts: int = 0
    _touching: bool = False


class Objects:
    """The world's graspable objects. Standing on the floor an object is a small circle the
    lidar sees (:meth:`circles`). :meth:`update` (each physics step, handed the robot's true
    pose and the arm's tool) picks one up when the fingers close on it — the opening falls
    below its radius while the arm stands (the tool point still in base_link) within
    ``tolerance`` of the object's centre — carries it at
    the tool point while held (lifted: the lidar no longer sees it) and puts it down where
    the tool point is when the fingers open past its radius. A footprint that overlaps an
    object standing on the floor counts a contact."""

    def __init__(self, tolerance: float = GRASP_TOLERANCE) -> None:
        self.tolerance = tolerance
        self.items: list[SimObject] = []
        self._opening: float | None = None
        self._tool: tuple[float, float] | None = None
        #: the nearest miss of the last close (m from the tool point to an object), or None
        self.last_miss_m: float | None = None
        #: the object's centre from the tool point at the last close: along the robot's
        #: heading and across it (m)
        self.last_offset: tuple[float, float] | None = None

    def place(self, x: float, y: float, radius: float = OBJECT_RADIUS,
              color: str = "red") -> SimObject:
        if not (math.isfinite(x) and math.isfinite(y) and radius > 0):
            raise ValueError(f"an object needs a finite position and radius > 0, got "
                             f"({x}, {y}), r {radius}")
        if color not in OBJECT_COLORS:
            raise ValueError(f"unknown object colour {color!r}; colours: "
                             f"{', '.join(OBJECT_COLORS)}")
        item = SimObject(x, y, radius, color=color)
        self.items.append(item)
        return item

    def clear(self) -> None:
        self.items.clear()
        self._opening = None

    def circles(self) -> np.ndarray:
        """``(N, 3)``: the objects standing on the floor (x, y, r) — what the lidar sees."""
        rows = [(o.x, o.y, o.radius) for o in self.items if not o.held]
        return np.array(rows, dtype=float).reshape(-1, 3)

    def standing(self) -> list[tuple[float, float, float, str]]:
        """The objects standing on the floor: (x, y, r, colour) — what the camera sees."""
        return [(o.x, o.y, o.radius, o.color) for o in self.items if not o.held]

    @property
    def held(self) -> SimObject | None:
        return next((o for o in self.items if o.held), None)

    @property
    def contacts(self) -> int:
        return sum(o.contacts for o in self.items)

    def update(self, x: float, y: float, theta: float, tool: Tool | None,
               footprint_radius: float) -> None:
        """The robot at (x, y, theta) with its arm's ``tool`` (None: no arm)."""
        for item in self.items:
            if item.held:
                continue
            touching = math.hypot(item.x - x, item.y - y) < footprint_radius + item.radius
            if touching and not item._touching:
                item.contacts += 1
            item._touching = touching
        if tool is None:
            return
        c, s = math.cos(theta), math.sin(theta)
        tx, ty = x + c * tool.x - s * tool.y, y + s * tool.x + c * tool.y
        before, self._opening = self._opening, tool.opening
        last, self._tool = self._tool, (tool.x, tool.y)
        standing = last is not None and math.hypot(tool.x - last[0], tool.y - last[1]) < 1e-4
        for item in self.items:
            if item.held:
                item.x, item.y = tx, ty
                if tool.opening > item.radius:
                    item.held = False  # released where the tool point is
                continue
        if before is None or not (before > tool.opening) or self.held is not None \
                or not standing:  # fingers closing while the arm swings away grasp nothing
            return
        closing_past = [o for o in self.items if before > o.radius >= tool.opening]
        if not closing_past:
            return
        nearest = min(closing_past, key=lambda o: math.hypot(o.x - tx, o.y - ty))
        distance = math.hypot(nearest.x - tx, nearest.y - ty)
        dx, dy = nearest.x - tx, nearest.y - ty
        self.last_offset = (c * dx + s * dy, -s * dx + c * dy)
        if distance <= self.tolerance:
            nearest.held, nearest.x, nearest.y = True, tx, ty
            self.last_miss_m = None
        else:
            self.last_miss_m = distance

    def miss(self) -> str:
        """What the last close that held nothing missed by ('' when nothing is known)."""
        if self.last_miss_m is None:
            return ""
        along, across = self.last_offset or (math.nan, math.nan)
        return (f"the tool point closed {self.last_miss_m:.3f} m from the object's centre "
                f"({along:+.3f} m ahead, {across:+.3f} m to the left), the tolerance is "
                f"{self.tolerance:g} m")

    def report(self) -> list[dict[str, float | bool | int | str]]:
        return [{"x": round(o.x, 4), "y": round(o.y, 4), "radius": o.radius, "held": o.held,
                 "contacts": o.contacts, "color": o.color} for o in self.items]


def cast_circles(ranges: np.ndarray, circles: np.ndarray, x: float, y: float, theta: float,
                 angles: np.ndarray, range_max: float = math.inf) -> np.ndarray:
    """``ranges`` (along ``theta + angles``, from (x, y)) shortened by the hits on
    ``circles`` (``(N, 3)``: x, y, r) nearer than ``range_max``; a copy. A circle over the
    origin is skipped."""
    out = np.array(ranges, dtype=float, copy=True)
    if not len(circles):
        return out
    dx, dy = np.cos(theta + angles), np.sin(theta + angles)
    for cx, cy, r in circles:
        ox, oy = cx - x, cy - y
        along = dx * ox + dy * oy
        offset = ox * ox + oy * oy - r * r
        if offset <= 0:
            continue
        with np.errstate(invalid="ignore"):
            t = along - np.sqrt(along * along - offset)
        hit = np.isfinite(t) & (t > 0) & (t < out) & (t <= range_max)
        out[hit] = t[hit]
    return out


#: what the arm's owner gives the world: the tool in base_link now, or None
ToolReader = Callable[[], Tool | None]
