# Driver benchmarks: command -> write latency of each driver against its emulator.
from __future__ import annotations

import importlib

from daemon.bench import BenchResult

# one module per driver, each with `run(quick) -> list[BenchResult]`
DRIVER_BENCHES = ("drivers.bench_serial", "drivers.bench_pigpio", "drivers.bench_odrive")


def run(quick: bool) -> list[BenchResult]:
    results: list[BenchResult] = []
    for module in DRIVER_BENCHES:
        results += importlib.import_module(module).run(quick)
    return results
