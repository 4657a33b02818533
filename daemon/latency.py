# Latency tracking: receipt -> driver write per command, client -> receipt, control tick lateness.
from __future__ import annotations

import time
from bisect import bisect_left
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np
from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, HistogramMetricFamily, Metric
from prometheus_client.registry import Collector
from prometheus_client.utils import floatToGoString

from daemon.telemetry import LatencyReport

PERCENTILES = (50, 90, 95, 99)
EXEC_BUCKETS = (5e-6, 1e-5, 2e-5, 5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 0.01, 0.05)
TRANSIT_BUCKETS = (1e-4, 5e-4, 1e-3, 2e-3, 5e-3, 0.01, 0.02, 0.05, 0.1, 0.5, 1.0)
TICK_BUCKETS = (5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 0.01, 0.02, 0.05, 0.1)
MAX_SOURCES = 64
SOURCE_IDLE_S = 600.0
CLOCK_NOTE = ("client wall clock vs daemon wall clock: only meaningful when the clocks are "
              "synchronised (same machine, or NTP/PTP)")


class Buckets:
    """A cumulative histogram kept as plain counts: one ``bisect`` and two additions per
    observation (prometheus_client's ``Histogram.observe`` takes a lock per bucket and costs
    about ten times more on the command path). Read on scrape by :class:`LatencyMetrics`."""

    __slots__ = ("bounds", "counts", "sum")

    def __init__(self, bounds: tuple[float, ...]) -> None:
        self.bounds = bounds
        self.counts = [0] * (len(bounds) + 1)  # the last one is +Inf
        self.sum = 0.0

    def observe(self, value: float) -> None:
        self.counts[bisect_left(self.bounds, value)] += 1  # le: a value on a bound counts in it
        self.sum += value

    def family(self, name: str, documentation: str) -> HistogramMetricFamily:
        cumulative, running = [], 0
        for bound, count in zip((*map(floatToGoString, self.bounds), "+Inf"), self.counts,
                                strict=True):
            running += count
            cumulative.append((bound, float(running)))
        return HistogramMetricFamily(name, documentation, buckets=cumulative,
                                     sum_value=self.sum)


class LatencyMetrics(Collector):
    """The latency figures for Prometheus, in a registry of their own (the collision monitor
    adds its counters there too). The command and tick paths only bump counts; the metric
    families are built when ``/metrics`` is scraped."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.exec_s = Buckets(EXEC_BUCKETS)
        self.transit_s = Buckets(TRANSIT_BUCKETS)
        self.tick_late_s = Buckets(TICK_BUCKETS)
        self.clock_skew = 0
        self.commands: dict[str, int] = {}  # by kind of source: ``ws:17`` counts as ``ws``
        self._kinds: dict[str, str] = {}
        self.registry.register(self)

    def count(self, source: str) -> None:
        """One applied command from ``source`` (labelled by kind: ``ws:17`` counts as ``ws``)."""
        kind = self._kinds.get(source)
        if kind is None:
            if len(self._kinds) >= 4 * MAX_SOURCES:
                self._kinds.clear()
            kind = self._kinds[source] = _source_kind(source)
        self.commands[kind] = self.commands.get(kind, 0) + 1

    def collect(self) -> Iterator[Metric]:
        yield self.exec_s.family("arbiterd_command_exec_seconds", "receipt -> driver write")
        yield self.transit_s.family("arbiterd_command_transit_seconds",
                                    "client send -> receipt (clock-dependent)")
        yield CounterMetricFamily("arbiterd_command_transit_negative", "stamped commands "
                                  "received before they were sent (clock skew)",
                                  value=self.clock_skew)
        commands = CounterMetricFamily("arbiterd_commands", "applied commands",
                                       labels=["source"])
        for kind, count in sorted(self.commands.items()):
            commands.add_metric([kind], count)
        yield commands
        yield self.tick_late_s.family("arbiterd_tick_lateness_seconds",
                                      "control tick start after its deadline")


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
        self._counts: OrderedDict[str, list[Any]] = OrderedDict()  # [count, last seen]
        self.dropped = 0

    def add(self, source: str) -> None:
        now = self.clock()
        entry = self._counts.get(source)
        if entry is None:
            self._counts[source] = [1, now]
        else:
            entry[0] += 1
            entry[1] = now
            self._counts.move_to_end(source)
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
        self._tick_buckets = self.metrics.tick_late_s
        self.per_source = SourceCounts()
        self.exec_ms: deque[float] = deque(maxlen=window)
        self.transit_ms: deque[float] = deque(maxlen=window)
        self.tick_late_ms: deque[float] = deque(maxlen=window)
        self.commands = 0
        self.ticks = 0
        self.late_ticks = 0
        self.missed_ticks = 0

    @staticmethod
    def report(t_recv_mono: float, t_exec_mono: float, *, source: str,
               cmd_id: str | int | None = None,
               t_sent_ms: float | None = None) -> LatencyReport:
        """One applied command's report (times are ``time.monotonic()`` seconds), not yet
        counted (:meth:`account` counts it: the control loop answers the sender first)."""
        exec_ms = (t_exec_mono - t_recv_mono) * 1e3
        wall_exec_ms = (time.time() - time.monotonic() + t_exec_mono) * 1e3
        return LatencyReport(cmd_id, t_sent_ms, wall_exec_ms - exec_ms, wall_exec_ms, exec_ms,
                             source)

    def account(self, report: LatencyReport) -> None:
        """Count one command's report in the statistics."""
        exec_ms, source, t_sent_ms = report.exec_ms, report.source, report.t_sent
        self.commands += 1
        self.per_source.add(source)
        self.exec_ms.append(exec_ms)
        self.metrics.exec_s.observe(exec_ms / 1e3)
        self.metrics.count(source)
        if t_sent_ms is not None:
            transit = report.t_recv - t_sent_ms
            self.transit_ms.append(transit)
            if transit < 0:
                self.metrics.clock_skew += 1
            else:
                self.metrics.transit_s.observe(transit / 1e3)

    def record_tick(self, lateness_s: float, late: bool) -> None:
        self.ticks += 1
        self.tick_late_ms.append(lateness_s * 1e3)
        buckets = self._tick_buckets  # Buckets.observe, inlined: 50 times a second
        value = lateness_s if lateness_s > 0.0 else 0.0
        buckets.counts[bisect_left(buckets.bounds, value)] += 1
        buckets.sum += value
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
