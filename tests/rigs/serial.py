# Rig for the serial driver: an emulated ROSArduinoBridge Arduino on a pseudo-terminal.
from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from sim.arduino_emulator import ArduinoEmulator
from sim.motor_model import MotorPair, WheelMotor

# High-resolution encoders keep the ticks-per-frame rounding of `m L R` small:
# one tick per 30 Hz frame is 2*pi*30/COUNTS_PER_REV = 0.046 rad/s.
COUNTS_PER_REV = 4096


class SerialRig:
    """The emulator, plus the ``[driver.serial]`` options that point the driver at it."""

    driver_name = "serial"
    wheel_sign = 1

    def __init__(self, emulator: ArduinoEmulator) -> None:
        self.emulator = emulator
        self.motors = emulator.motors
        self.options: dict[str, Any] = {
            "port": str(emulator.link),
            "counts_per_rev": COUNTS_PER_REV,
            "reset_wait_s": 0.05,
            "timeout_s": 1.0,
        }

    def observed_targets(self) -> tuple[float, float]:
        """The wheel set-points the firmware last applied (ticks per frame as rad/s)."""
        return self.motors.targets()

    @property
    def quantum_rad_s(self) -> float:
        """The speed of one encoder tick per PID frame: the resolution of ``m L R``."""
        return self.emulator.firmware.ticks_to_rad_s(1, COUNTS_PER_REV)


def make_motors(counts_per_rev: int = COUNTS_PER_REV) -> MotorPair:
    return MotorPair(WheelMotor(counts_per_rev=counts_per_rev),
                     WheelMotor(counts_per_rev=counts_per_rev))


@asynccontextmanager
async def rig(tmp_path: Path) -> AsyncIterator[SerialRig]:
    emulator = ArduinoEmulator(tmp_path / "arduino", make_motors(), boot_s=0.01)
    with emulator:
        yield SerialRig(emulator)
