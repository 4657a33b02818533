# systemd notify protocol: READY, STATUS, WATCHDOG (from on-time ticks only), STOPPING.
from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping

log = logging.getLogger("arbiterd.systemd")


class SystemdNotifier:
    """sdnotify with the watchdog handling it leaves out.

    sdnotify reads ``NOTIFY_SOCKET`` once and ignores ``WATCHDOG_USEC``/``WATCHDOG_PID``; this
    reads both, checks the PID, and pets the watchdog at half the interval, only when the
    control tick reports it ran on time. Without ``NOTIFY_SOCKET`` everything is a no-op.
    """

    def __init__(self, env: Mapping[str, str] | None = None) -> None:
        env = os.environ if env is None else env
        self.enabled = bool(env.get("NOTIFY_SOCKET"))
        self._notifier = None
        if self.enabled:
            import sdnotify

            self._notifier = sdnotify.SystemdNotifier()
        self.watchdog_interval_s = self._watchdog_interval(env)
        self._last_ping = 0.0
        self.pings = 0
        self.last_status = ""

    @staticmethod
    def _watchdog_interval(env: Mapping[str, str]) -> float | None:
        usec = env.get("WATCHDOG_USEC")
        pid = env.get("WATCHDOG_PID")
        if not usec or (pid and pid != str(os.getpid())):
            return None
        try:
            return int(usec) / 1e6 / 2.0
        except ValueError:
            log.warning("ignoring WATCHDOG_USEC=%r: not an integer", usec)
            return None

    def send(self, message: str) -> None:
        if self._notifier is not None:
            self._notifier.notify(message)

    def ready(self, status: str) -> None:
        self.last_status = status
        self.send(f"READY=1\nSTATUS={status}")

    def status(self, status: str) -> None:
        if status != self.last_status:
            self.last_status = status
            self.send(f"STATUS={status}")

    def stopping(self, status: str) -> None:
        self.send(f"STOPPING=1\nSTATUS={status}")

    def tick(self, now: float, on_time: bool) -> None:
        """Called from every control tick; pets the watchdog when due and healthy."""
        if self.watchdog_interval_s is None or not on_time:
            return
        if now - self._last_ping >= self.watchdog_interval_s:
            self._last_ping = now
            self.pings += 1
            self.send("WATCHDOG=1")


def monotonic() -> float:
    return time.monotonic()
