# One check for every coordinate and pose that comes in (HTTP, rosbridge, DDS, missions, fetch).
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

#: without a map, no coordinate may be farther from its frame's origin than this (m): far
#: beyond any room or yard this robot maps, and small enough that a grid cell index computed
#: from it is an ordinary integer (1e16 killed the mapper, 1e308 overflowed a cell index)
MAX_COORDINATE_M = 10_000.0
#: with a map, how far outside its extent a pose may still be (m): the robot may stand just
#: beyond what the lidar has seen
EXTENT_MARGIN_M = 5.0
#: the largest angle taken (rad); any heading is within ±π, but clients send degrees by mistake
MAX_ANGLE_RAD = 1000.0


class CoordinateError(ValueError):
    """A coordinate or pose refused; ``field`` names it (``x``, ``pose.position.y``,
    ``waypoints[3][0]``) and the text starts with it, for a 4xx the client can act on."""

    def __init__(self, field: str, problem: str) -> None:
        super().__init__(f"{field}: {problem}")
        self.field = field


@dataclass(frozen=True)
class Extent:
    """The area a map covers (m, in its frame); :meth:`check` allows :data:`EXTENT_MARGIN_M`
    around it."""

    min_x: float
    min_y: float
    max_x: float
    max_y: float
    what: str = "the map"

    def check(self, x: float, y: float, field: str, margin: float = EXTENT_MARGIN_M) -> None:
        if not (self.min_x - margin <= x <= self.max_x + margin
                and self.min_y - margin <= y <= self.max_y + margin):
            raise CoordinateError(field, f"({x:.2f}, {y:.2f}) is outside {self.what} "
                                  f"(x {self.min_x:.2f}..{self.max_x:.2f}, y {self.min_y:.2f}.."
                                  f"{self.max_y:.2f} m, {margin:g} m margin)")


def number(value: Any, field: str) -> float:
    """A finite JSON number (not a boolean, not a string)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        kind = "nothing" if value is None else type(value).__name__
        raise CoordinateError(field, f"expected a finite number, got {kind}")
    try:
        out = float(value)
    except OverflowError:  # an integer beyond a float's range
        raise CoordinateError(field, "expected a finite number, got a huge integer") from None
    if not math.isfinite(out):
        raise CoordinateError(field, f"expected a finite number, got {out!r}")
    return out


def coordinate(value: Any, field: str, bound: float = MAX_COORDINATE_M) -> float:
    """A position coordinate (m): finite, at most ``bound`` from the origin."""
    out = number(value, field)
    if abs(out) > bound:
        raise CoordinateError(field, f"{out:g} m is beyond ±{bound:g} m (the largest "
                              "coordinate taken)")
    return out


def angle(value: Any, field: str) -> float:
    """An angle (rad): finite, at most :data:`MAX_ANGLE_RAD`."""
    out = number(value, field)
    if abs(out) > MAX_ANGLE_RAD:
        raise CoordinateError(field, f"{out:g} rad is beyond ±{MAX_ANGLE_RAD:g} rad")
    return out


def point(values: Sequence[Any], fields: Sequence[str], extent: Extent | None = None,
          ) -> tuple[float, float]:
    """(x, y) from two values named by ``fields``; inside ``extent`` when there is one."""
    x, y = coordinate(values[0], fields[0]), coordinate(values[1], fields[1])
    if extent is not None:
        extent.check(x, y, f"{fields[0]}, {fields[1]}")
    return x, y


def required(message: Mapping[str, Any], path: str) -> Any:
    """The value at dotted ``path`` in a message as the client sent it (before defaults were
    filled in), or :class:`CoordinateError` naming what is missing."""
    value: Any = message
    walked = []
    for key in path.split("."):
        walked.append(key)
        if not isinstance(value, Mapping) or key not in value:
            raise CoordinateError(".".join(walked), "missing (required)")
        value = value[key]
    return value


def missing_required(message: Any, paths: Sequence[str]) -> str | None:
    """Why ``message`` (as sent) lacks one of ``paths``, or None: what a transport asks of an
    incoming topic's declared ``required`` fields before the message's defaults fill them."""
    if not isinstance(message, Mapping):
        return None  # the type check says what is wrong with it
    for path in paths:
        try:
            required(message, path)
        except CoordinateError as exc:
            return str(exc)
    return None
