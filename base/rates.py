# A token bucket: a sustained rate with a burst, on a clock the caller gives.
from __future__ import annotations

from collections.abc import Callable


class TokenBucket:
    """``rate`` units per second sustained, up to ``burst`` at once."""

    def __init__(self, rate: float, burst: float, clock: Callable[[], float]) -> None:
        self.rate = rate
        self.burst = float(burst)
        self.clock = clock
        self._tokens = float(burst)
        self._t_last = clock()

    def take(self, units: float = 1.0) -> bool:
        """Take ``units`` if they are there; False (nothing taken) if not."""
        self._refill()
        if self._tokens < units:
            return False
        self._tokens -= units
        return True

    def reserve(self, units: float) -> float:
        """Take ``units`` now, on credit if need be; the seconds until they are paid for."""
        self._refill()
        self._tokens -= units
        return max(0.0, -self._tokens / self.rate)

    def take_up_to(self, units: int) -> int:
        """Take as many whole units as are there, at most ``units``; how many were taken."""
        self._refill()
        taken = min(units, max(0, int(self._tokens)))
        self._tokens -= taken
        return taken

    def level(self) -> float:
        """Units there now (negative: owed)."""
        self._refill()
        return self._tokens

    @property
    def left(self) -> float:
        """Units there after the last take or reserve (negative: owed), without a refill."""
        return self._tokens

    def _refill(self) -> None:
        now = self.clock()
        self._tokens = min(self.burst, self._tokens + (now - self._t_last) * self.rate)
        self._t_last = now
