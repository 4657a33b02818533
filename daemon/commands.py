# Velocity commands: parsing Twist-shaped JSON strictly, refusing anything not finite.
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from daemon import coords

VECTOR_FIELDS = ("x", "y", "z")
TWIST_FIELDS = ("linear", "angular")
#: the largest speed a command may ask for (m/s, rad/s): far beyond any robot this drives, so
#: a real command is clamped by the limiter, while 1e308 is a bad request, not full speed
MAX_COMMAND = 100.0
_EMPTY: dict[str, float] = {}


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


_AXIS = {"x": 0, "y": 1, "z": 2}


def parse_vector(value: Any, field: str, prefix: str = "") -> list[float]:
    """``{"x", "y", "z"}`` (absent = 0) as ``[x, y, z]``; plain finite floats take a fast path.
    Errors name ``prefix + field`` (joined only when there is an error)."""
    if type(value) is not dict and not isinstance(value, Mapping):  # dict: no ABC check
        raise CommandError(f"{prefix}{field}: expected an object with x, y, z")
    out = [0.0, 0.0, 0.0]
    for key, number in value.items():
        index = _AXIS.get(key)
        if index is None:
            raise CommandError(f"{prefix}{field}.{key}: unknown field")
        if type(number) is float and number - number == 0.0:  # finite (inf-inf, nan are nan)
            out[index] = number
        else:
            out[index] = finite_number(number, f"{prefix}{field}.{key}")
    return out


def parse_twist(body: Mapping[str, Any], *, extra: tuple[str, ...] = (),
                prefix: str = "") -> Twist:
    """A Twist from ``{"linear": {...}, "angular": {...}}``; absent fields are 0.

    Keys listed in ``extra`` are allowed beside ``linear``/``angular`` (and read by the
    caller). Components a differential-drive base cannot do (linear y/z, angular x/y) must be
    zero, so a command is never silently reduced to something else.
    """
    for key in body:
        if key not in TWIST_FIELDS and key not in extra:
            raise CommandError(f"{prefix}{key}: unknown field")
    lx, ly, lz = parse_vector(body.get("linear", _EMPTY), "linear", prefix)
    ax, ay, az = parse_vector(body.get("angular", _EMPTY), "angular", prefix)
    if ly or lz or ax or ay:
        field, value = next((f, v) for f, v in (("linear.y", ly), ("linear.z", lz),
                                                ("angular.x", ax), ("angular.y", ay)) if v)
        raise CommandError(f"{prefix}{field}: a differential-drive base cannot move "
                           f"along this axis; must be 0, got {value}")
    if not (-MAX_COMMAND <= lx <= MAX_COMMAND and -MAX_COMMAND <= az <= MAX_COMMAND):
        field, value = ("linear.x", lx) if abs(lx) > MAX_COMMAND else ("angular.z", az)
        raise CommandError(f"{prefix}{field}: {value:g} is beyond ±{MAX_COMMAND:g} (the "
                           "largest command taken; the limiter clamps to the robot's own)")
    return Twist(lx, az)


POSE_FIELDS = ("x", "y", "theta")


def parse_pose(body: Mapping[str, Any]) -> tuple[float, float, float] | None:
    """``{"x", "y", "theta"}`` (m, m, rad; each 0 when absent) or None for ``{}``; a field of
    another name, or not a coordinate :mod:`daemon.coords` takes, is :class:`CommandError`
    naming it."""
    unknown = sorted(set(body) - set(POSE_FIELDS))
    if unknown:
        raise CommandError(f"{unknown[0]}: unknown field")
    if not body:
        return None
    try:
        return (coords.coordinate(body.get("x", 0.0), "x"),
                coords.coordinate(body.get("y", 0.0), "y"), coords.angle(body.get("theta", 0.0),
                                                                          "theta"))
    except coords.CoordinateError as exc:
        raise CommandError(str(exc)) from None


STAMP_FIELDS = ("id", "t_sent")

Stamped = tuple[Twist, str | int | None, float | None]


def plain_stamped(body: Any) -> Stamped | None:
    """(twist, id, t_sent) of a stamped command in its common shape, checked in one pass:
    ``linear``/``angular`` objects of finite floats (the axes a differential-drive base cannot
    do at zero), a string or integer ``id``, a finite float ``t_sent``. None for anything
    else, which :func:`parse_twist` and :func:`parse_stamp` then accept or refuse: what this
    returns is what they return."""
    if type(body) is not dict:
        return None
    lx = az = 0.0
    cmd_id = t_sent = None
    for key, value in body.items():
        if key == "linear" or key == "angular":  # finite floats on x, y, z; only one not 0
            if type(value) is not dict:
                return None
            wanted = "x" if key == "linear" else "z"
            speed = 0.0
            for axis, number in value.items():
                if type(number) is not float or number - number != 0.0 or axis not in _AXIS \
                        or (number and axis != wanted):
                    return None
                if axis == wanted:
                    if not -MAX_COMMAND <= number <= MAX_COMMAND:
                        return None  # the general parse refuses it, naming the field
                    speed = number
            if key == "linear":
                lx = speed
            else:
                az = speed
        elif key == "id":
            if type(value) is not str and type(value) is not int:
                return None
            cmd_id = value
        elif key == "t_sent" and type(value) is float and value - value == 0.0:
            t_sent = value
        else:
            return None
    return Twist(lx, az), cmd_id, t_sent


def parse_stamp(body: Mapping[str, Any],
                prefix: str = "") -> tuple[str | int | None, float | None]:
    """The optional ``id`` (string or integer) and ``t_sent`` (client wall clock, ms)."""
    cmd_id = body.get("id")
    if cmd_id is not None and (isinstance(cmd_id, bool) or not isinstance(cmd_id, str | int)):
        raise CommandError(f"{prefix}id: expected a string or integer")
    t_sent = body.get("t_sent")
    if t_sent is not None:
        t_sent = finite_number(t_sent, f"{prefix}t_sent")
    return cmd_id, t_sent
