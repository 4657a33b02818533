# Benchmark: command -> write latency of the serial driver against the emulated Arduino.
from __future__ import annotations

import asyncio
import tempfile
from pathlib import Path

from daemon.bench import BenchResult
from daemon.bench.driver_emulated import on_emulator, stage_results, time_commands
from sim.arduino_emulator import ArduinoEmulator

SPEEDS_RAD_S = [0.5 * step for step in range(-20, 21) if step]  # distinct wire commands


def run(quick: bool) -> list[BenchResult]:
    count = 300 if quick else 3000
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-") as tmp:
        return asyncio.run(_measure(Path(tmp), count))


async def _measure(workdir: Path, count: int) -> list[BenchResult]:
    async with on_emulator("serial", workdir, max_wheel_speed=20.0) as (driver, emulated):
        board: ArduinoEmulator = emulated.emulator

        async def arrival(speed: float, since: float) -> float | None:
            return _board_time(board, driver.health()["wire_command"], since)

        to_return, to_board = await time_commands(driver, SPEEDS_RAD_S, count, arrival,
                                                  mirror=True, pause_s=0.002)
        poll_hz = emulated.options["poll_rate"]
    note = (f"{count} set_wheel_speeds calls with 'e' polled at {poll_hz:g} Hz; emulator thread "
            "in the same process over a pty; a real board adds ~2.4 ms of 57600-baud wire time")
    return stage_results("serial", ("ack", "board"), to_return, to_board,
                         (note, "until the emulated firmware parsed the command"))


def _board_time(emulator: ArduinoEmulator, command: str, since: float) -> float | None:
    for received in reversed(emulator.firmware.history):
        if received.t_mono < since:
            return None
        if received.text == command:
            return received.t_mono
    return None
