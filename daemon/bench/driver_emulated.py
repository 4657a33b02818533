# What the driver benches share: a registered driver on its emulator (sim/wiring.py), timed.
from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from base.options import defaults
from daemon.bench import BenchResult, ms_result, percentile_ms
from drivers import MotorDriver, create_driver, driver_class
from sim.motor_model import MotorPair
from sim.wiring import EMULATORS, Emulated

SUITE = "drivers"

# when the emulator saw the command for ``speed`` sent at monotonic ``since`` (None: not seen)
Arrival = Callable[[float, float], Awaitable[float | None]]


@asynccontextmanager
async def on_emulator(name: str, workdir: Path, *, max_wheel_speed: float,
                      motors: MotorPair | None = None,
                      **options: Any) -> AsyncIterator[tuple[MotorDriver, Emulated]]:
    """The driver ``name`` (``options`` on top of its defaults), opened against its emulator
    as ``arbiterd run --sim`` wires it."""
    wiring = EMULATORS[name]
    section = defaults(driver_class(name).OPTIONS) | options
    emulated = wiring.start(motors or wiring.motors(), workdir, section)
    try:
        driver = create_driver(name, section | emulated.options, max_wheel_speed=max_wheel_speed)
        await driver.open()
        try:
            yield driver, emulated
        finally:
            await driver.close()
    finally:
        emulated.stop()


async def time_commands(driver: MotorDriver, speeds: Sequence[float], count: int,
                        arrival: Arrival, *, mirror: bool = False,
                        pause_s: float = 0.0) -> tuple[list[float], list[float]]:
    """Seconds from each ``set_wheel_speeds`` call to its return, and to the emulator having
    it; the right wheel gets ``-speed`` with ``mirror``."""
    to_return: list[float] = []
    to_device: list[float] = []
    for i in range(count):
        speed = speeds[i % len(speeds)]
        start = time.monotonic()
        await driver.set_wheel_speeds(speed, -speed if mirror else speed)
        to_return.append(time.monotonic() - start)
        seen = await arrival(speed, start)
        if seen is not None:
            to_device.append(seen - start)
        await asyncio.sleep(pause_s)
    return to_return, to_device


def stage_results(label: str, stages: tuple[str, str], to_return: list[float],
                  to_device: list[float], notes: tuple[str, str]) -> list[BenchResult]:
    """p50 and p99 of both stages, in milliseconds: ``label command->stage pNN``."""
    results = []
    for stage, samples, note in zip(stages, (to_return, to_device), notes, strict=True):
        results.append(ms_result(SUITE, f"{label} command->{stage} p50",
                                 percentile_ms(samples, 50), note))
        results.append(ms_result(SUITE, f"{label} command->{stage} p99",
                                 percentile_ms(samples, 99)))
    return results
