# A retry loop's failures in the log: the reason once, then only a short line now and then.
from __future__ import annotations

import logging
import time
from collections.abc import Callable

#: how often a retry loop that keeps failing for the same reason says so
STILL_FAILING_EVERY_S = 60.0


class RetryLog:
    """Logs the failures of a retry loop (a device that is missing, a link that is down).

    A reason not logged before is logged in full, once; further failures for the same reason
    (or for a part of the reason logged last: a fault line that gave it more context) log one
    short line every ``every_s`` seconds with the count, so a device missing for a day is not
    a long line at every retry. :meth:`succeeded` forgets the reason.
    """

    def __init__(self, logger: logging.Logger, what: str,
                 every_s: float = STILL_FAILING_EVERY_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.logger = logger
        self.what = what
        self.every_s = every_s
        self.clock = clock
        self.reason: str | None = None
        self.attempts = 0
        self._since = 0.0
        self._said = 0.0

    def known(self, reason: str) -> None:
        """``reason`` was just logged elsewhere (a fault line): retries failing for it are
        short from the start."""
        self.reason, self.attempts = reason, 0
        self._since = self._said = self.clock()

    def failed(self, reason: str, retry_s: float, level: int = logging.WARNING) -> None:
        now = self.clock()
        if self.reason is None or reason not in self.reason:
            self.known(reason)
            self.attempts = 1
            self.logger.log(level, "%s: %s; retrying in %.1f s", self.what, reason, retry_s)
            return
        self.attempts += 1
        if now - self._said >= self.every_s:
            self._said = now
            self.logger.log(level, "%s: still failing, %d attempts in %.0f s (same reason); "
                            "retrying every %.1f s", self.what, self.attempts, now - self._since,
                            retry_s)

    def succeeded(self) -> None:
        self.reason, self.attempts = None, 0
