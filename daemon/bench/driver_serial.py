# Benchmark: command -> write latency of the serial driver against the emulated Arduino.
from __future__ import annotations

import asyncio
import tempfile
import time
from pathlib import Path

from daemon.bench import BenchResult, ms_result, percentile_ms
from drivers.arduino_serial import SerialBridgeDriver
from sim.arduino_emulator import ArduinoEmulator

SUITE = "drivers"
SPEEDS_RAD_S = [0.5 * step for step in range(-20, 21) if step]  # distinct wire commands


def run(quick: bool) -> list[BenchResult]:
    count = 300 if quick else 3000
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-") as tmp:
        return asyncio.run(_measure(Path(tmp) / "arduino", count))


async def _measure(link: Path, count: int) -> list[BenchResult]:
    with ArduinoEmulator(link) as emulator:
        driver = SerialBridgeDriver({"port": str(link), "reset_wait_s": 0.05, "timeout_s": 1.0},
                                    max_wheel_speed=20.0)
        await driver.open()
        try:
            to_return, to_board = await _time_commands(driver, emulator, count)
        finally:
            await driver.close()
    note = (f"{count} set_wheel_speeds calls with 'e' polled at 30 Hz; emulator thread in the "
            "same process over a pty; a real board adds ~2.4 ms of 57600-baud wire time")
    return [
        ms_result(SUITE, "serial command->ack p50", percentile_ms(to_return, 50), note),
        ms_result(SUITE, "serial command->ack p99", percentile_ms(to_return, 99), ""),
        ms_result(SUITE, "serial command->board p50", percentile_ms(to_board, 50),
                "until the emulated firmware parsed the command"),
        ms_result(SUITE, "serial command->board p99", percentile_ms(to_board, 99), ""),
    ]


async def _time_commands(driver: SerialBridgeDriver, emulator: ArduinoEmulator,
                         count: int) -> tuple[list[float], list[float]]:
    to_return: list[float] = []
    to_board: list[float] = []
    for i in range(count):
        speed = SPEEDS_RAD_S[i % len(SPEEDS_RAD_S)]
        start = time.monotonic()
        await driver.set_wheel_speeds(speed, -speed)
        to_return.append(time.monotonic() - start)
        seen = _board_time(emulator, driver.health()["wire_command"], start)
        if seen is not None:
            to_board.append(seen - start)
        await asyncio.sleep(0.002)
    return to_return, to_board


def _board_time(emulator: ArduinoEmulator, command: str, since: float) -> float | None:
    for received in reversed(emulator.firmware.history):
        if received.t_mono < since:
            return None
        if received.text == command:
            return received.t_mono
    return None
