# Velocity commands: parsing Twist-shaped JSON strictly, refusing anything not finite.
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

VECTOR_FIELDS = ("x", "y", "z")
TWIST_FIELDS = ("linear", "angular")


class CommandError(ValueError):
    """A command that is refused; the message names the offending field."""


@dataclass(frozen=True)
class Twist:
    """A planar base velocity: forward m/s and yaw rate rad/s."""

    linear_x: float = 0.0
    angular_z: float = 0.0

    @property
    def is_zero(self) -> bool:
        return self.linear_x == 0.0 and self.angular_z == 0.0


ZERO = Twist()


def finite_number(value: Any, field: str) -> float:
    """``value`` as a float, or :class:`CommandError` naming ``field``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CommandError(f"{field}: expected a number, got {type(value).__name__} {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise CommandError(f"{field}: must be finite, got {value}")
    return number


def parse_vector(value: Any, field: str) -> dict[str, float]:
    if not isinstance(value, Mapping):
        raise CommandError(f"{field}: expected an object with x, y, z")
    unknown = sorted(set(value) - set(VECTOR_FIELDS))
    if unknown:
        raise CommandError(f"{field}.{unknown[0]}: unknown field")
    return {axis: finite_number(value.get(axis, 0.0), f"{field}.{axis}") for axis in VECTOR_FIELDS}


def parse_twist(body: Mapping[str, Any], *, extra: tuple[str, ...] = (),
                prefix: str = "") -> Twist:
    """A Twist from ``{"linear": {...}, "angular": {...}}``; absent fields are 0.

    Keys listed in ``extra`` are allowed beside ``linear``/``angular`` (and read by the
    caller). Components a differential-drive base cannot do (linear y/z, angular x/y) must be
    zero, so a command is never silently reduced to something else.
    """
    unknown = sorted(set(body) - set(TWIST_FIELDS) - set(extra))
    if unknown:
        raise CommandError(f"{prefix}{unknown[0]}: unknown field")
    linear = parse_vector(body.get("linear", {}), f"{prefix}linear")
    angular = parse_vector(body.get("angular", {}), f"{prefix}angular")
    for field, value in (("linear.y", linear["y"]), ("linear.z", linear["z"]),
                         ("angular.x", angular["x"]), ("angular.y", angular["y"])):
        if value != 0.0:
            raise CommandError(f"{prefix}{field}: a differential-drive base cannot move "
                               f"along this axis; must be 0, got {value}")
    return Twist(linear["x"], angular["z"])
