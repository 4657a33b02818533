# Benchmark: command -> CAN frame latency of the odrive_can driver against the emulated ODrive.
from __future__ import annotations

import asyncio
import math
import socket
import tempfile
import time
from collections import deque
from collections.abc import AsyncIterator
from contextlib import AbstractAsyncContextManager, asynccontextmanager
from pathlib import Path

from daemon.bench import BenchResult
from daemon.bench.driver_emulated import SUITE, on_emulator, stage_results, time_commands
from drivers import MotorDriver
from drivers.base import DriverError
from drivers.cansimple import CMD_SET_INPUT_VEL, encode_set_input_vel
from drivers.odrive_can import ODriveCanDriver
from sim.odrive_emulator import DEFAULT_MULTICAST_GROUP, ODriveEmulator

SPEEDS_RAD_S = [1.0 + 0.01 * step for step in range(500)]  # distinct values: each frame matches
Frames = deque[tuple[bytes, float]]
Connection = AbstractAsyncContextManager[tuple[MotorDriver, ODriveEmulator]]


def run(quick: bool) -> list[BenchResult]:
    count = 300 if quick else 3000
    with tempfile.TemporaryDirectory(prefix="arbiterd-bench-") as tmp:
        results = asyncio.run(_measure("virtual", _on_virtual_bus(Path(tmp)), count))
    try:
        results += asyncio.run(_measure("udp_multicast", _on_multicast(), count))
    except (DriverError, OSError, ImportError) as exc:
        results.append(BenchResult(SUITE, "odrive_can udp_multicast", 0.0, "ms",
                                   note=f"not measured: udp_multicast unusable here ({exc})"))
    return results


@asynccontextmanager
async def _on_virtual_bus(workdir: Path) -> AsyncIterator[tuple[MotorDriver, ODriveEmulator]]:
    """As ``arbiterd run --sim`` wires it: a python-can virtual channel of its own."""
    async with on_emulator("odrive_can", workdir, max_wheel_speed=40.0,
                           keepalive_period_s=0.0) as (driver, emulated):
        yield driver, emulated.emulator


@asynccontextmanager
async def _on_multicast() -> AsyncIterator[tuple[MotorDriver, ODriveEmulator]]:
    """Across sockets: python-can's udp_multicast interface, as two processes would talk."""
    port = _free_udp_port()
    with ODriveEmulator("udp_multicast", DEFAULT_MULTICAST_GROUP,
                        bus_kwargs={"port": port}) as emulator:
        driver = ODriveCanDriver({"interface": "udp_multicast",
                                  "channel": DEFAULT_MULTICAST_GROUP, "multicast_port": port,
                                  "keepalive_period_s": 0.0}, max_wheel_speed=40.0)
        await driver.open()
        try:
            yield driver, emulator
        finally:
            await driver.close()


async def _measure(interface: str, connect: Connection, count: int) -> list[BenchResult]:
    async with connect as (driver, emulator):
        seen: Frames = deque(maxlen=64)
        right = emulator.axis("right")
        right_sign = -1 if driver.settings.right_motor_inverted else 1

        def record(node: int, cmd: int, data: bytes, t_mono: float) -> None:
            if node == right.node_id and cmd == CMD_SET_INPUT_VEL:
                seen.append((data[:4], t_mono))

        async def arrival(speed: float, since: float) -> float | None:
            # the right motor is mirrored: its frame carries the negated turns per second
            payload = encode_set_input_vel(right_sign * speed / (2 * math.pi))[:4]
            return await _arrival(seen, payload, since)

        emulator.frame_hooks.append(record)
        to_return, to_odrive = await time_commands(driver, SPEEDS_RAD_S, count, arrival)
    note = (f"{count} set_wheel_speeds calls; emulator thread in this process on python-can "
            f"{interface}; on a real CAN bus each 8-byte frame adds ~0.25 ms at 500 kbit/s")
    return stage_results(f"odrive_can {interface}", ("sent", "ODrive"), to_return, to_odrive,
                         (note, f"until the emulated ODrive handled the right wheel's "
                                f"Set_Input_Vel ({len(to_odrive)} matched)"))


async def _arrival(seen: Frames, payload: bytes, since: float,
                   limit_s: float = 1.0) -> float | None:
    deadline = since + limit_s
    while time.monotonic() < deadline:
        for data, t_mono in reversed(seen):
            if t_mono >= since and data == payload:
                return t_mono
        await asyncio.sleep(0.0005)
    return None


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("", 0))
        port: int = sock.getsockname()[1]
        return port
