# Benchmark: command -> write latency of the pigpio and l298n drivers against the pigpiod emulator.
from __future__ import annotations

import asyncio
import threading
import time
from typing import Any

from daemon.bench import BenchResult, ms_result, percentile_ms
from drivers.base import MotorDriver
from drivers.l298n import L298NDriver
from drivers.pigpio_pwm import PigpioDriver
from sim.pigpiod_emulator import (
    CMD_HP,
    CMD_PWM,
    CMD_WRITE,
    HBridge,
    PigpiodEmulator,
    Request,
    Wiring,
    default_motors,
)

SUITE = "drivers"
FULL_DUTY_SPEED = 20.0
SPEEDS_RAD_S = [0.5 * step for step in range(1, 31)]  # distinct duties, one direction
WRITE_COMMANDS = (CMD_PWM, CMD_HP, CMD_WRITE)


class WriteClock:
    """Monotonic times at which the emulator executed output writes (its command hook)."""

    def __init__(self) -> None:
        self.times: list[float] = []
        self._lock = threading.Lock()

    def __call__(self, req: Request, t_mono: float) -> None:
        if req.cmd in WRITE_COMMANDS:
            with self._lock:
                self.times.append(t_mono)

    def last_since(self, since: float) -> float | None:
        with self._lock:
            recent = [t for t in self.times[-8:] if t >= since]
        return max(recent) if recent else None


def run(quick: bool) -> list[BenchResult]:
    count = 300 if quick else 3000
    return asyncio.run(_all(count))


async def _all(count: int) -> list[BenchResult]:
    results: list[BenchResult] = []
    pigpio_opts = {"host": "127.0.0.1", "max_wheel_speed": FULL_DUTY_SPEED,
                   "watch_interval": 0.0}
    results += await _bench("pigpio", Wiring(HBridge(23, 24, 12), HBridge(27, 22, 13)),
                            lambda port: PigpioDriver(pigpio_opts | {"port": port},
                                                      max_wheel_speed=FULL_DUTY_SPEED),
                            count, "hardware PWM on GPIO 12/13: one HP command per wheel")
    l298n_opts = {"pin_factory": "pigpio", "pigpio_host": "127.0.0.1",
                  "max_wheel_speed": FULL_DUTY_SPEED, "watch_interval": 0.0}
    results += await _bench("l298n (PiGPIOFactory)", Wiring(HBridge(17, 18), HBridge(22, 23)),
                            lambda port: L298NDriver(l298n_opts | {"pigpio_port": port},
                                                     max_wheel_speed=FULL_DUTY_SPEED),
                            count, "gpiozero reads range and duty before each PWM write")
    results += await _bench_mock(count)
    return results


async def _bench(label: str, wiring: Wiring, make: Any, count: int,
                 note: str) -> list[BenchResult]:
    emulator = PigpiodEmulator(wiring, default_motors()).start()
    clock = WriteClock()
    emulator.bank.on_command = clock
    try:
        driver: MotorDriver = make(emulator.port)
        await driver.open()
        try:
            to_return, to_pins = await _time_commands(driver, clock, count)
        finally:
            await driver.close()
    finally:
        emulator.close()
    note = (f"{count} set_wheel_speeds calls, pigpiod emulator in the same process over "
            f"loopback TCP; {note}")
    return [
        ms_result(SUITE, f"{label} command->return p50", percentile_ms(to_return, 50), note),
        ms_result(SUITE, f"{label} command->return p99", percentile_ms(to_return, 99), ""),
        ms_result(SUITE, f"{label} command->pigpiod p50", percentile_ms(to_pins, 50),
                "until the emulated pigpiod executed the last write of the command"),
        ms_result(SUITE, f"{label} command->pigpiod p99", percentile_ms(to_pins, 99), ""),
    ]


async def _bench_mock(count: int) -> list[BenchResult]:
    driver = L298NDriver({"pin_factory": "mock", "max_wheel_speed": FULL_DUTY_SPEED},
                         max_wheel_speed=FULL_DUTY_SPEED)
    await driver.open()
    try:
        to_return, _ = await _time_commands(driver, None, count)
    finally:
        await driver.close()
    name = "l298n (MockFactory) command->return"
    return [ms_result(SUITE, f"{name} p50", percentile_ms(to_return, 50),
                      f"{count} calls; gpiozero's own cost with no I/O"),
            ms_result(SUITE, f"{name} p99", percentile_ms(to_return, 99))]


async def _time_commands(driver: MotorDriver, clock: WriteClock | None,
                         count: int) -> tuple[list[float], list[float]]:
    to_return: list[float] = []
    to_pins: list[float] = []
    for i in range(count):
        speed = SPEEDS_RAD_S[i % len(SPEEDS_RAD_S)]
        start = time.monotonic()
        await driver.set_wheel_speeds(speed, speed)
        to_return.append(time.monotonic() - start)
        seen = clock.last_since(start) if clock is not None else None
        if seen is not None:
            to_pins.append(seen - start)
        await asyncio.sleep(0.001)
    return to_return, to_pins
