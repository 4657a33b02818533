# A motor driver whose wheels are the simulated world's motors (no wire, virtual time).
from __future__ import annotations

from dataclasses import dataclass

from daemon.clock import Clock
from drivers.base import EncoderReading, MotorDriver
from sim.motor_model import MotorPair


@dataclass(frozen=True)
class WorldSettings:
    """The world driver has no options."""


class WorldDriver(MotorDriver):
    """Commands set the world's wheel targets; encoders read the world's wheel positions
    (with the world's encoder noise), stamped with the virtual clock."""

    SETTINGS = WorldSettings

    def __init__(self, motors: MotorPair, clock: Clock, *, max_wheel_speed: float) -> None:
        super().__init__({}, max_wheel_speed=max_wheel_speed)
        self.motors = motors
        self.clock = clock

    @classmethod
    def name(cls) -> str:
        return "world"

    async def _open(self) -> None:
        pass

    async def _apply(self, left_rad_s: float, right_rad_s: float) -> None:
        self.motors.set_targets(left_rad_s, right_rad_s)

    def _read_encoders(self) -> EncoderReading | None:
        left, right = self.motors.positions()
        return EncoderReading(left, right, self.clock())

    async def _close(self) -> None:
        pass

    def _emergency_zero(self) -> bool:
        self.motors.set_targets(0.0, 0.0)
        return True
