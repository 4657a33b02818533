# Test rigs: each registered driver wired to the emulator that speaks its real protocol.
from __future__ import annotations

import importlib
from collections.abc import AsyncIterator, Callable
from contextlib import AbstractAsyncContextManager
from typing import Any, Protocol


class Rig(Protocol):
    """A driver's emulator, running, plus what the contract test needs to check it.

    ``options`` is the ``[driver.<name>]`` section pointing the real driver at the emulator;
    ``motors`` is the emulator's :class:`sim.motor_model.MotorPair` (what the hardware does).
    ``wheel_sign`` maps the emulator's wheel direction to the robot's forward direction
    (the same for both wheels).
    """

    driver_name: str
    options: dict[str, Any]
    motors: Any

    def observed_targets(self) -> tuple[float, float]:
        """Wheel speed set-points (rad/s, forward positive) the emulated hardware last received."""
        ...


RigFactory = Callable[[Any], AbstractAsyncContextManager[Rig]]

# driver name (or variant) => "module:function" returning an async context manager of a Rig;
# the function takes pytest's tmp_path.
RIGS: dict[str, str] = {
    "mock": "tests.rigs.mock:rig",
    "serial": "tests.rigs.serial:rig",
    "pigpio": "tests.rigs.pigpio:rig",
    "odrive_can": "tests.rigs.odrive_can:rig",
    "l298n": "tests.rigs.l298n:rig",
    "l298n@pigpio": "tests.rigs.l298n:rig_pigpio",
}


def rig_factory(name: str) -> RigFactory:
    module_name, func = RIGS[name].split(":")
    factory: RigFactory = getattr(importlib.import_module(module_name), func)
    return factory


__all__ = ["RIGS", "AsyncIterator", "Rig", "rig_factory"]
