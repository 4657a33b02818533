# Benchmark: command -> write latency of the pigpio and l298n drivers against the pigpiod emulator.
from __future__ import annotations

import asyncio
import tempfile
import threading
from pathlib import Path

from daemon.bench import BenchResult, ms_result, percentile_ms
from daemon.bench.driver_emulated import SUITE, on_emulator, stage_results, time_commands
from drivers.l298n import L298NDriver
from sim.pigpiod_emulator import CMD_HP, CMD_PWM, CMD_WRITE, PigpiodEmulator, Request
from sim.wiring import EMULATORS

FULL_DUTY_SPEED = 20.0
SPEEDS_RAD_S = [0.5 * step for step in range(1, 31)]  # distinct duties, one direction
WRITE_COMMANDS = (CMD_PWM, CMD_HP, CMD_WRITE)
NOTES = {
    "pigpio": ("pigpio", "hardware PWM on GPIO 12/13: one HP command per wheel"),
    "l298n": ("l298n (PiGPIOFactory)", "gpiozero reads range and duty before each PWM write"),
}


class WriteClock:
    """Monotonic times at which the emulator executed output writes (its command hook)."""

    def __init__(self) -> None:
        self.times: list[float] = []
        self._lock = threading.Lock()

    def __call__(self, req: Request, t_mono: float) -> None:
        if req.cmd in WRITE_COMMANDS:
            with self._lock:
                self.times.append(t_mono)

    async def last_since(self, speed: float, since: float) -> float | None:
        with self._lock:
            recent = [t for t in self.times[-8:] if t >= since]
        return max(recent) if recent else None


def run(quick: bool) -> list[BenchResult]:
    count = 300 if quick else 3000
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-") as tmp:
        return asyncio.run(_all(Path(tmp), count))


async def _all(workdir: Path, count: int) -> list[BenchResult]:
    results: list[BenchResult] = []
    for name in NOTES:
        results += await _bench(name, workdir, count)
    return results + await _bench_mock(count)


async def _bench(name: str, workdir: Path, count: int) -> list[BenchResult]:
    motors = EMULATORS[name].motors(max_speed_rad_s=FULL_DUTY_SPEED)
    clock = WriteClock()
    async with on_emulator(name, workdir, max_wheel_speed=FULL_DUTY_SPEED, motors=motors,
                           watch_interval=0.0) as (driver, emulated):
        pigpiod: PigpiodEmulator = emulated.emulator
        pigpiod.bank.on_command = clock
        to_return, to_pins = await time_commands(driver, SPEEDS_RAD_S, count, clock.last_since,
                                                 pause_s=0.001)
    label, detail = NOTES[name]
    note = (f"{count} set_wheel_speeds calls, pigpiod emulator in the same process over "
            f"loopback TCP, encoders on; {detail}")
    return stage_results(label, ("return", "pigpiod"), to_return, to_pins,
                         (note, "until the emulated pigpiod executed the last write of the "
                                "command"))


async def _bench_mock(count: int) -> list[BenchResult]:
    driver = L298NDriver({"pin_factory": "mock", "max_wheel_speed": FULL_DUTY_SPEED},
                         max_wheel_speed=FULL_DUTY_SPEED)
    await driver.open()
    try:
        to_return, _ = await time_commands(driver, SPEEDS_RAD_S, count, _unseen, pause_s=0.001)
    finally:
        await driver.close()
    name = "l298n (MockFactory) command->return"
    return [ms_result(SUITE, f"{name} p50", percentile_ms(to_return, 50),
                      f"{count} calls; gpiozero's own cost with no I/O"),
            ms_result(SUITE, f"{name} p99", percentile_ms(to_return, 99))]


async def _unseen(speed: float, since: float) -> float | None:
    return None
