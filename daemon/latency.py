# Latency tracking: receipt -> driver write per command, client -> receipt, control tick lateness.
from __future__ import annotations

import time
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
from prometheus_client import CollectorRegistry, Counter, Histogram

from daemon.telemetry import LatencyReport

PERCENTILES = (50, 90, 95, 99)
EXEC_BUCKETS = (5e-6, 1e-5, 2e-5, 5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 0.01, 0.05)
TRANSIT_BUCKETS = (1e-4, 5e-4, 1e-3, 2e-3, 5e-3, 0.01, 0.02, 0.05, 0.1, 0.5, 1.0)
TICK_BUCKETS = (5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 0.01, 0.02, 0.05, 0.1)
MAX_SOURCES = 64
SOURCE_IDLE_S = 600.0
CLOCK_NOTE = ("client wall clock vs daemon wall clock: only meaningful when the clocks are "
              "synchronised (same machine, or NTP/PTP)")


class LatencyMetrics:
    """The latency figures as Prometheus histograms, in a registry of their own."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.exec_s = Histogram("arbiterd_command_exec_seconds", "receipt -> driver write",
                                buckets=EXEC_BUCKETS, registry=self.registry)
        self.transit_s = Histogram("arbiterd_command_transit_seconds", "client send -> "
                                   "receipt (clock-dependent)", buckets=TRANSIT_BUCKETS,
                                   registry=self.registry)
        self.clock_skew = Counter("arbiterd_command_transit_negative", "stamped commands "
                                  "received before they were sent (clock skew)",
                                  registry=self.registry)
        self.commands = Counter("arbiterd_commands", "applied commands", ["source"],
                                registry=self.registry)
        self.tick_late_s = Histogram("arbiterd_tick_lateness_seconds", "control tick start "
                                     "after its deadline", buckets=TICK_BUCKETS,
                                     registry=self.registry)
        self._per_kind: dict[str, Any] = {}

    def count(self, source: str) -> None:
        """One applied command from ``source`` (labelled by kind: ``ws:17`` counts as ``ws``)."""
        child = self._per_kind.get(source)
        if child is None:
            child = self._per_kind[source] = self.commands.labels(_source_kind(source))
        child.inc()


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


class SourceCounts:
    """Commands per source (``http``, ``ws:17``, ...), bounded: at most ``max_sources``
    entries, least recently active first out, and a source silent for ``idle_s`` is dropped."""

    def __init__(self, max_sources: int = MAX_SOURCES, idle_s: float = SOURCE_IDLE_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.max_sources = max_sources
        self.idle_s = idle_s
        self.clock = clock
        self._counts: OrderedDict[str, tuple[int, float]] = OrderedDict()
        self.dropped = 0

    def add(self, source: str) -> None:
        now = self.clock()
        count, _ = self._counts.pop(source, (0, now))
        self._counts[source] = (count + 1, now)
        self._expire(now)

    def _expire(self, now: float) -> None:
        while self._counts:
            oldest, (_, last) = next(iter(self._counts.items()))
            if len(self._counts) <= self.max_sources and now - last < self.idle_s:
                return
            del self._counts[oldest]
            self.dropped += 1

    def snapshot(self) -> dict[str, int]:
        self._expire(self.clock())
        return {source: count for source, (count, _) in self._counts.items()}

    def __len__(self) -> int:
        return len(self._counts)


class LatencyTracker:
    """Rolling windows of command latency and tick lateness, for ``/api/latency``."""

    def __init__(self, window: int = 2000) -> None:
        self.window = window
        self.metrics = LatencyMetrics()
        self.per_source = SourceCounts()
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
        wall_exec_ms = (time.time() - time.monotonic() + t_exec_mono) * 1e3
        wall_recv_ms = wall_exec_ms - exec_ms
        self.commands += 1
        self.per_source.add(source)
        self.exec_ms.append(exec_ms)
        self.metrics.exec_s.observe(exec_ms / 1e3)
        self.metrics.count(source)
        if t_sent_ms is not None:
            transit = wall_recv_ms - t_sent_ms
            self.transit_ms.append(transit)
            if transit < 0:
                self.metrics.clock_skew.inc()
            else:
                self.metrics.transit_s.observe(transit / 1e3)
        return LatencyReport(cmd_id, t_sent_ms, wall_recv_ms, wall_exec_ms, exec_ms, source)

    def record_tick(self, lateness_s: float, late: bool) -> None:
        self.ticks += 1
        self.tick_late_ms.append(lateness_s * 1e3)
        self.metrics.tick_late_s.observe(max(0.0, lateness_s))
        if late:
            self.late_ticks += 1

    def stats(self) -> dict[str, Any]:
        return {
            "window": self.window,
            "commands": self.commands,
            "receipt_to_exec_ms": summarize(self.exec_ms),
            "client_to_receipt_ms": {**summarize(self.transit_ms), "clock_dependent": True,
                                     "note": CLOCK_NOTE},
            "per_source": self.per_source.snapshot(),
            "per_source_limits": {"max_sources": self.per_source.max_sources,
                                  "idle_expiry_s": self.per_source.idle_s,
                                  "dropped": self.per_source.dropped},
            "tick": {"count": self.ticks, "late": self.late_ticks,
                     "missed": self.missed_ticks, "lateness_ms": summarize(self.tick_late_ms)},
        }


def _source_kind(source: str) -> str:
    """``ws:17`` -> ``ws``: one label value per kind of source, not per client."""
    return source.split(":", 1)[0]
