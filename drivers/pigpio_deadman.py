# A deadman inside pigpiod: a script that zeroes the motor pins unless the driver feeds it.
from __future__ import annotations

import math
import time
from collections.abc import Iterable
from typing import Any

#: the script's step (ms): it counts p0 down once per step
STEP_MS = 20


def script_text(pwm: Iterable[tuple[int, int]], low: Iterable[int]) -> bytes:
    """The script: count p0 down every :data:`STEP_MS`; at -1 set each PWM pin's duty to 0
    (``(pin, hardware PWM frequency)``, 0 = DMA PWM) and each direction pin low, once; then
    wait for p0 to be fed above 0 again."""
    zero = [f"hp {pin} {freq} 0" if freq else f"pwm {pin} 0" for pin, freq in pwm]
    zero += [f"w {pin} 0" for pin in low]
    return " ".join([f"tag 0 mils {STEP_MS} dcr p0 jp 0", *zero, "inr p1",
                     f"tag 1 mils {STEP_MS} lda p0 cmp 1 jm 1 jmp 0"]).encode()


class Deadman:
    """Stores and runs the script on a pigpio connection and feeds it: every feed sets p0 to
    the steps in ``seconds``. :meth:`feed` says when the pins must all be written again
    (the last feed was so long ago that the script may have zeroed them)."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.steps = max(1, math.ceil(seconds * 1000 / STEP_MS))
        self.script_id: int | None = None
        self._fed = -math.inf

    @property
    def enabled(self) -> bool:
        return self.seconds > 0

    def start(self, pi: Any, pwm: Iterable[tuple[int, int]], low: Iterable[int]) -> None:
        if not self.enabled:
            return
        self.script_id = pi.store_script(script_text(pwm, low))
        pi.run_script(self.script_id, [self.steps, 0])
        self._fed = time.monotonic()

    def feed(self, pi: Any) -> bool:
        """Feed it; True when the pins may have been zeroed since the last feed."""
        if self.script_id is None:
            return False
        now = time.monotonic()
        stale = now - self._fed > self.seconds / 2
        pi.update_script(self.script_id, [self.steps])
        self._fed = now
        return stale

    def trips(self, pi: Any) -> int | None:
        """How often the script has zeroed the pins (its p1), or None without it."""
        if self.script_id is None:
            return None
        status, params = pi.script_status(self.script_id)
        return int(params[1]) if status >= 0 else None

    def stop(self, pi: Any) -> None:
        script_id, self.script_id = self.script_id, None
        if script_id is not None:
            pi.delete_script(script_id)
