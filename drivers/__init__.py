# Motor driver registry: one table (drivers.registry), name -> class, imported only when chosen.
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from drivers.base import (
    DriverClosed,
    DriverError,
    DriverFault,
    EncoderReading,
    MotorDriver,
    registered_class,
)
from drivers.registry import DRIVERS

__all__ = ["DRIVERS", "DriverClosed", "DriverError", "DriverFault", "EncoderReading",
           "MotorDriver", "UnknownDriver", "create_driver", "driver_class"]


class UnknownDriver(DriverError, LookupError):
    """A driver name that is not in the registry."""


def driver_class(name: str) -> type[MotorDriver]:
    """Import and return the class registered as ``name``."""
    cls: type[MotorDriver] = registered_class(DRIVERS, name, "driver", UnknownDriver,
                                              DriverError)
    return cls


def create_driver(name: str, options: Mapping[str, Any], *, max_wheel_speed: float) -> MotorDriver:
    """Build (but do not open) the driver registered as ``name`` from its ``[driver.<name>]``
    options (missing keys take their defaults). A bad option is a ``ValueError`` naming the
    section and key."""
    return driver_class(name)(options, max_wheel_speed=max_wheel_speed)
