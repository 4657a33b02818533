# Benchmark suite registry: suite name -> module with `run(quick) -> list[BenchResult]`.
from __future__ import annotations

import asyncio
import logging
from collections.abc import Coroutine
from dataclasses import asdict, dataclass
from typing import Any, TypeVar

T = TypeVar("T")


@dataclass
class BenchResult:
    """One measured figure, with its target when it has one."""

    suite: str
    name: str
    value: float
    unit: str
    target: str = ""
    ok: bool | None = None
    note: str = ""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def percentile_ms(samples_s: list[float], pct: float) -> float:
    """The ``pct`` percentile (nearest rank) of durations in seconds, in milliseconds."""
    if not samples_s:
        return float("nan")
    ordered = sorted(samples_s)
    index = min(len(ordered) - 1, max(0, round(pct / 100 * (len(ordered) - 1))))
    return ordered[index] * 1e3


def ms_result(suite: str, name: str, value_ms: float, note: str = "") -> BenchResult:
    """A millisecond figure without a target."""
    return BenchResult(suite, name, round(value_ms, 4), "ms", note=note)


def run_quietly(main: Coroutine[Any, Any, T]) -> T:
    """Run a suite's coroutine with the daemon's own log quiet (errors only)."""
    arbiterd_log = logging.getLogger("arbiterd")
    level = arbiterd_log.level
    arbiterd_log.setLevel(logging.ERROR)
    try:
        return asyncio.run(main)
    finally:
        arbiterd_log.setLevel(level)


# suite name => module; each module has `def run(quick: bool) -> list[BenchResult]`
SUITES: dict[str, str] = {
    "control": "daemon.bench.control",
    "lidar": "daemon.bench.lidar",
    "drivers": "daemon.bench.drivers",
    "sim": "daemon.bench.sim",
    "process": "daemon.bench.process",
    "rosbridge": "daemon.bench.rosbridge",
    "console": "daemon.bench.console",
    "rosbridge-flood": "daemon.bench.rosbridge_flood",
    "safety": "daemon.bench.safety",
    "foxglove": "daemon.bench.foxglove",
}
