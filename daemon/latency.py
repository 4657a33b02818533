# Latency tracking: receipt -> driver write per command, client -> receipt, control tick lateness.
from __future__ import annotations

import time
from collections import deque
from collections.abc import Iterable
from typing import Any

import numpy as np

from daemon.telemetry import LatencyReport

PERCENTILES = (50, 90, 95, 99)


def summarize(samples: Iterable[float]) -> dict[str, Any]:
    """count, p50/p90/p95/p99, max and mean of a window of millisecond samples."""
    values = np.fromiter(samples, dtype=float)
    if values.size == 0:
        return {"count": 0}
    out: dict[str, Any] = {"count": int(values.size)}
    for p, v in zip(PERCENTILES, np.percentile(values, PERCENTILES), strict=True):
        out[f"p{p}"] = round(float(v), 4)
    out["max"] = round(float(values.max()), 4)
    out["mean"] = round(float(values.mean()), 4)
    return out


class LatencyTracker:
    """Rolling windows of command latency and tick lateness, for ``/api/latency``."""

    def __init__(self, window: int = 2000) -> None:
        self.window = window
        self.exec_ms: deque[float] = deque(maxlen=window)
        self.transit_ms: deque[float] = deque(maxlen=window)
        self.tick_late_ms: deque[float] = deque(maxlen=window)
        self.commands = 0
        self.ticks = 0
        self.late_ticks = 0
        self.missed_ticks = 0

    def record_command(self, t_recv_mono: float, t_exec_mono: float, *, source: str,
                       cmd_id: str | int | None = None,
                       t_sent_ms: float | None = None) -> LatencyReport:
        """Record one applied command; times are ``time.monotonic()`` seconds."""
        exec_ms = (t_exec_mono - t_recv_mono) * 1e3
        wall_exec_ms = time.time() * 1e3 - (time.monotonic() - t_exec_mono) * 1e3
        wall_recv_ms = wall_exec_ms - exec_ms
        self.commands += 1
        self.exec_ms.append(exec_ms)
        if t_sent_ms is not None:
            self.transit_ms.append(wall_recv_ms - t_sent_ms)
        return LatencyReport(cmd_id, t_sent_ms, round(wall_recv_ms, 4), round(wall_exec_ms, 4),
                             round(exec_ms, 4), source)

    def record_tick(self, lateness_s: float, late: bool) -> None:
        self.ticks += 1
        self.tick_late_ms.append(lateness_s * 1e3)
        if late:
            self.late_ticks += 1

    def stats(self) -> dict[str, Any]:
        return {
            "window": self.window,
            "commands": self.commands,
            "receipt_to_exec_ms": summarize(self.exec_ms),
            "client_to_receipt_ms": summarize(self.transit_ms),
            "tick": {"count": self.ticks, "late": self.late_ticks,
                     "missed": self.missed_ticks, "lateness_ms": summarize(self.tick_late_ms)},
        }
