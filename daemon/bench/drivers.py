# Driver benchmarks: command -> write latency of each driver against its emulator (sim/wiring.py).
from __future__ import annotations

from daemon.bench import BenchResult, driver_odrive, driver_pigpio, driver_serial

# one module per driver, each with `run(quick) -> list[BenchResult]`
DRIVER_BENCHES = (driver_serial, driver_pigpio, driver_odrive)


def run(quick: bool) -> list[BenchResult]:
    results: list[BenchResult] = []
    for module in DRIVER_BENCHES:
        results += module.run(quick)
    return results
