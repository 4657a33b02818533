# The control code's clock: monotonic seconds handed in from outside (real or virtual time).
from __future__ import annotations

import time
from collections.abc import Callable

#: What the control loop, the collision monitor and the autonomy read the time from.
Clock = Callable[[], float]

#: The real clock of the running daemon.
MONOTONIC: Clock = time.monotonic


class VirtualClock:
    """A clock that only moves when told to (``arbiterd simulate`` steps it in lockstep with
    the simulated world). Time is kept as a whole number of ticks of ``resolution`` seconds so
    that long runs do not accumulate rounding drift."""

    def __init__(self, resolution: float = 1e-6) -> None:
        self.resolution = resolution
        self._ticks = 0

    def __call__(self) -> float:
        return self._ticks * self.resolution

    def set(self, t: float) -> None:
        """Move to ``t`` seconds; the clock never runs backwards."""
        ticks = round(t / self.resolution)
        if ticks < self._ticks:
            raise ValueError(f"virtual time cannot go back from {self()} s to {t} s")
        self._ticks = ticks

    def advance(self, dt: float) -> None:
        self.set(self() + dt)
