# Mock driver: records every command with its time; ideal wheels give exact encoders.
from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

from base.options import option
from drivers.base import EncoderReading, MotorDriver


class RecordedCommand(NamedTuple):
    """One write the mock driver saw: monotonic time and wheel speeds in rad/s."""

    t_mono: float
    left_rad_s: float
    right_rad_s: float


@dataclass(frozen=True)
class MockSettings:
    """The ``[driver.mock]`` section: its keys, each declared once (``OPTIONS`` is made from
    them)."""

    encoders: bool = option(True, "report ideal encoder positions (closed-loop odometry)")
    history: int = option(100000, "how many commands to keep in memory", minval=1)
    log_file: str = option("", "append every command to this file ('' = off)")


class MockDriver(MotorDriver):
    """A registered driver with no hardware: ideal wheels that follow each command at once.

    Encoders integrate the commanded speeds, so odometry through this driver is exact. Every
    command is recorded (bounded by ``history``) for tests and ``arbiterd bench``; with
    ``log_file`` set, every command is also appended there as ``t_mono left right``, so a test
    can watch a daemon subprocess's wheels.
    """

    SETTINGS = MockSettings
    settings: MockSettings

    def __init__(self, options: Mapping[str, Any], *, max_wheel_speed: float) -> None:
        super().__init__(options, max_wheel_speed=max_wheel_speed)
        self.commands: deque[RecordedCommand] = deque(maxlen=self.settings.history)
        self._positions = [0.0, 0.0]
        self._speeds = (0.0, 0.0)
        self._since = time.monotonic()
        self._log: Any = None
        self._lock = threading.Lock()  # commands from the event loop and emergency_stop()
        #: called with (left, right) after every write (the simulator turns its wheels here)
        self.listeners: list[Callable[[float, float], None]] = []
        #: where the encoders read the wheels' positions (rad), when something turns real
        #: wheels for the commands (the simulator's motors); None: the commands integrated
        self.encoder_source: Callable[[], tuple[float, float]] | None = None

    async def _open(self) -> None:
        self._since = time.monotonic()
        self._speeds = (0.0, 0.0)
        if self.settings.log_file:
            self._log = open(self.settings.log_file, "a", buffering=1)  # noqa: SIM115, ASYNC230

    async def _apply(self, left_rad_s: float, right_rad_s: float) -> None:
        self._record(left_rad_s, right_rad_s)

    def _read_encoders(self) -> EncoderReading | None:
        if not self.settings.encoders:
            return None
        if self.encoder_source is not None:
            left, right = self.encoder_source()
            return EncoderReading(left, right, time.monotonic())
        with self._lock:
            now = time.monotonic()
            self._integrate(now)
            return EncoderReading(self._positions[0], self._positions[1], now)

    async def _close(self) -> None:
        self._integrate(time.monotonic())
        self._speeds = (0.0, 0.0)
        if self._log is not None:
            self._log.close()
            self._log = None

    def _integrate(self, now: float) -> None:
        dt = now - self._since
        self._positions[0] += self._speeds[0] * dt
        self._positions[1] += self._speeds[1] * dt
        self._since = now

    def _health(self) -> dict[str, Any]:
        return {"recorded_commands": len(self.commands)}

    def _emergency_zero(self) -> bool:
        self._record(0.0, 0.0)
        return True

    def _record(self, left_rad_s: float, right_rad_s: float) -> None:
        """Take one command (the event loop's or the emergency path's), under the lock."""
        with self._lock:
            now = time.monotonic()
            self._integrate(now)
            self._speeds = (left_rad_s, right_rad_s)
            self.commands.append(RecordedCommand(now, left_rad_s, right_rad_s))
            if self._log is not None:
                self._log.write(f"{now:.6f} {left_rad_s:.6f} {right_rad_s:.6f}\n")
            for listener in self.listeners:
                listener(left_rad_s, right_rad_s)
