# Benchmark suite registry: suite name -> module with `run(quick) -> list[BenchResult]`.
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


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


# suite name => module; each module has `def run(quick: bool) -> list[BenchResult]`
SUITES: dict[str, str] = {
    "control": "daemon.bench.control",
    "lidar": "sensors.rplidar.bench",
    "drivers": "daemon.bench.drivers",
    "sim": "sim.bench",
    "process": "daemon.bench.process",
    "rosbridge": "daemon.bench.rosbridge",
}
