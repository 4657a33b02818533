# Rig for the pigpio driver: the pigpiod emulator on an ephemeral port, L298N bridges, encoders.
from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from drivers.pigpio_pwm import PigpioDriver
from sim.motor_model import MotorPair
from sim.pigpiod_emulator import PigpiodEmulator, Wiring, default_motors, pigpio_driver_wiring

#: Wheel speed at full duty in the emulated motors and the driver's map (rad/s).
FULL_DUTY_SPEED = 20.0
#: Encoder edges per revolution in the emulator: modest, so the notification rate stays sane.
COUNTS_PER_REV = 200


class PigpioRig:
    """The pigpiod emulator as the contract test sees it."""

    driver_name = "pigpio"

    def __init__(self, emulator: PigpiodEmulator, options: dict[str, Any]) -> None:
        self.emulator = emulator
        self.options = options
        self.motors = emulator.motors
        self.wheel_sign = 1.0

    def observed_targets(self) -> tuple[float, float]:
        return self.motors.targets()


def wiring_for(options: dict[str, Any], *, reverse: tuple[bool, bool] = (False, False)) -> Wiring:
    """The emulated hardware that matches a ``[driver.pigpio]`` section."""
    opts = {k: o.default for k, o in PigpioDriver.OPTIONS.items()} | options
    return pigpio_driver_wiring(opts, reverse)


def base_options(**overrides: Any) -> dict[str, Any]:
    return {
        "host": "127.0.0.1",
        "max_wheel_speed": FULL_DUTY_SPEED,
        "encoders": True,
        "encoder_counts_per_rev": COUNTS_PER_REV,
        "watch_interval": 0.05,
        "timeout": 0.5,
    } | overrides


@asynccontextmanager
async def running_rig(motors: MotorPair | None = None, *,
                      reverse: tuple[bool, bool] = (False, False),
                      **overrides: Any) -> AsyncIterator[PigpioRig]:
    """A started emulator wired like the options say; ``port`` is filled in."""
    options = base_options(**overrides)
    motors = motors or default_motors(COUNTS_PER_REV, FULL_DUTY_SPEED)
    emulator = PigpiodEmulator(wiring_for(options, reverse=reverse), motors).start()
    options["port"] = emulator.port
    try:
        yield PigpioRig(emulator, options)
    finally:
        emulator.close()


@asynccontextmanager
async def rig(tmp_path: Path) -> AsyncIterator[PigpioRig]:
    async with running_rig() as the_rig:
        yield the_rig
