# Servos without hardware: every pulse written is recorded (tests, and an arm without a board).
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from typing import Any, ClassVar

from base.options import Option, Options
from drivers.servo_array import CALIBRATION_OPTIONS, CalibrationSettings, ServoArray

MOCK_SERVO_OPTIONS: Options = {
    "channels": Option(list, [0], "each joint's output number, in joint order", item=int,
                       minval=0, maxval=63),
    **CALIBRATION_OPTIONS,
    "history": Option(int, 10000, "how many writes to keep", minval=1, maxval=1_000_000),
}


@dataclass(frozen=True)
class MockServoSettings(CalibrationSettings):
    channels: list[int]
    history: int


class MockServos(ServoArray):
    """Records each write: ``pulses`` (output => µs now, 0 = off) and ``history``
    ((monotonic time, {output: µs}) per write)."""

    OPTIONS: ClassVar[Options] = MOCK_SERVO_OPTIONS
    SETTINGS = MockServoSettings
    OUTPUTS_KEY = "channels"
    OUTPUT_NOUN = "a channel"

    def __init__(self, options: Any, *, section: str) -> None:
        super().__init__(options, section=section)
        self.pulses: dict[int, float] = dict.fromkeys(self.outputs.values(), 0.0)
        self.history: deque[tuple[float, dict[int, float]]] = deque(
            maxlen=self.settings.history)

    async def _open(self) -> None:
        return None

    async def _close(self) -> None:
        return None

    async def _send_pulses(self, pulses: dict[int, float]) -> None:
        self.pulses.update(pulses)
        self.history.append((time.monotonic(), dict(pulses)))

    def servo_pulse_us(self, output: int) -> float:
        """The pulse width an output carries now, µs (0 = off)."""
        return self.pulses.get(output, 0.0)
