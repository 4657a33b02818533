# The robot's footprint (a radius or a polygon): clearance of scan points and covering discs.
from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]

#: most covering discs a polygon footprint is split into
MAX_DISCS = 6


class FootprintError(ValueError):
    """A footprint that cannot be used; says what is wrong with it."""


@dataclass(frozen=True)
class Footprint:
    """The robot's outline in its own frame (x forward, y left, metres).

    A circle of ``radius`` about the origin, or a polygon. ``discs`` (``(D, 3)``: centre x,
    centre y, radius) cover the outline; the swept-path check moves these discs, so a polygon
    is checked slightly conservatively. ``reach`` is the circumscribed radius.
    """

    radius: float
    polygon: Array | None = None
    discs: Array = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.polygon is None:
            if not self.radius > 0:
                raise FootprintError(f"footprint radius must be > 0, got {self.radius}")
            discs = np.array([[0.0, 0.0, self.radius]])
        else:
            discs = covering_discs(self.polygon)
        object.__setattr__(self, "discs", discs)

    @classmethod
    def circle(cls, radius: float) -> Footprint:
        return cls(radius)

    @classmethod
    def from_points(cls, points: Sequence[Sequence[float]]) -> Footprint:
        """A polygon from ``[[x, y], ...]`` (at least 3 corners, the origin inside)."""
        polygon = np.asarray(points, dtype=float)
        if polygon.ndim != 2 or polygon.shape[1] != 2 or len(polygon) < 3:
            raise FootprintError("a footprint polygon needs at least 3 [x, y] corners")
        if not np.isfinite(polygon).all():
            raise FootprintError("footprint corners must be finite numbers")
        if _signed_distance(polygon, np.zeros(1), np.zeros(1))[0] >= 0:
            raise FootprintError("the robot's origin (0, 0) must lie inside the footprint "
                                 "polygon")
        return cls(float(np.hypot(polygon[:, 0], polygon[:, 1]).max()), polygon)

    @property
    def round(self) -> bool:
        """A single disc about the origin: turning in place sweeps nothing."""
        return self.polygon is None

    @property
    def reach(self) -> float:
        return self.radius

    def clearance(self, px: Array, py: Array) -> Array:
        """Distance from each point to the outline, negative inside the footprint."""
        if self.polygon is None:
            return np.asarray(np.hypot(px, py) - self.radius)
        return _signed_distance(self.polygon, px, py)


def _signed_distance(polygon: Array, px: Array, py: Array) -> Array:
    """Distance from each point to the polygon's edges, negative for points inside."""
    ax, ay = polygon[:, 0:1], polygon[:, 1:2]
    bx, by = np.roll(polygon[:, 0], -1)[:, None], np.roll(polygon[:, 1], -1)[:, None]
    ex, ey = bx - ax, by - ay
    qx, qy = px[None, :] - ax, py[None, :] - ay
    u = np.clip((qx * ex + qy * ey) / (ex * ex + ey * ey), 0.0, 1.0)
    distance = np.hypot(qx - u * ex, qy - u * ey).min(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        crosses = ((ay > py[None, :]) != (by > py[None, :])) & (
            px[None, :] < ex * (py[None, :] - ay) / ey + ax)
    inside = crosses.sum(axis=0) % 2 == 1
    return np.asarray(np.where(inside, -distance, distance))


def covering_discs(polygon: Array) -> Array:
    """Discs whose union covers the polygon: the polygon is cut into slabs across its longer
    side (about as long as the shorter side is wide), one disc per slab."""
    xs, ys = polygon[:, 0], polygon[:, 1]
    swap = np.ptp(ys) > np.ptp(xs)
    if swap:
        polygon = polygon[:, ::-1]
    lo, hi = float(polygon[:, 0].min()), float(polygon[:, 0].max())
    width = max(float(np.ptp(polygon[:, 1])), 1e-9)
    count = min(MAX_DISCS, max(1, math.ceil((hi - lo) / width - 1e-9)))
    edges = np.linspace(lo, hi, count + 1)
    discs = []
    for x0, x1 in itertools.pairwise(edges):
        part = _clip_slab(polygon, float(x0), float(x1))
        cx, cy = (x0 + x1) / 2.0, (part[:, 1].min() + part[:, 1].max()) / 2.0
        r = float(np.hypot(part[:, 0] - cx, part[:, 1] - cy).max())
        discs.append((cx, cy, r) if not swap else (cy, cx, r))
    return np.array(discs, dtype=float)


def _clip_slab(polygon: Array, x0: float, x1: float) -> Array:
    """The part of the polygon with x0 <= x <= x1 (Sutherland-Hodgman, two half-planes)."""
    points = [(float(x), float(y)) for x, y in polygon]
    for bound, sign in ((x0, 1.0), (x1, -1.0)):
        out: list[tuple[float, float]] = []
        for i, current in enumerate(points):
            previous = points[i - 1]
            inside_now = sign * (current[0] - bound) >= 0
            inside_before = sign * (previous[0] - bound) >= 0
            if inside_now != inside_before:
                out.append(_cross_x(previous, current, bound))
            if inside_now:
                out.append(current)
        points = out
    return np.array(points, dtype=float)


def _cross_x(a: tuple[float, float], b: tuple[float, float], x: float) -> tuple[float, float]:
    t = (x - a[0]) / (b[0] - a[0])
    return x, a[1] + t * (b[1] - a[1])
