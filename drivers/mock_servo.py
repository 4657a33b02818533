# Servos without hardware: every pulse written is recorded (tests, and an arm without a board).
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from base.options import option
from drivers.servo_array import CalibrationSettings, ServoArray


@dataclass(frozen=True)
class MockServoSettings(CalibrationSettings):
    """A mock_servo device's keys: each joint's output number and how much to keep."""

    channels: list[int] = option([0], "each joint's output number, in joint order", minval=0,
                                 maxval=63)
    history: int = option(10000, "how many writes to keep", minval=1, maxval=1_000_000)


class MockServos(ServoArray):
    """Records each write: ``pulses`` (output => µs now, 0 = off) and ``history``
    ((monotonic time, {output: µs}) per write)."""

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
