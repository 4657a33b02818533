# Benchmark: command -> CAN frame latency of the odrive_can driver against the emulated ODrive.
from __future__ import annotations

import asyncio
import socket
import struct
import time
import uuid
from collections import deque
from typing import Any

from daemon.bench import BenchResult
from daemon.latency import summarize
from drivers.base import DriverError
from drivers.odrive_can import CMD_SET_INPUT_VEL, ODriveCanDriver
from sim.odrive_emulator import ODriveEmulator

SUITE = "drivers"
LEFT_NODE, RIGHT_NODE = 0, 1
MULTICAST_GROUP = "239.74.163.2"


def run(quick: bool) -> list[BenchResult]:
    count = 300 if quick else 3000
    results = asyncio.run(_measure("virtual", f"bench-{uuid.uuid4().hex[:8]}", {}, count))
    port = _free_udp_port()
    try:
        results += asyncio.run(_measure("udp_multicast", MULTICAST_GROUP, {"port": port},
                                        count))
    except (DriverError, OSError, ImportError) as exc:
        results.append(BenchResult(SUITE, "odrive_can udp_multicast", 0.0, "ms",
                                   note=f"not measured: udp_multicast unusable here ({exc})"))
    return results


async def _measure(interface: str, channel: str, bus_kwargs: dict[str, Any],
                   count: int) -> list[BenchResult]:
    seen: deque[tuple[bytes, float]] = deque(maxlen=64)

    def record(node: int, cmd: int, data: bytes, t_mono: float) -> None:
        if node == RIGHT_NODE and cmd == CMD_SET_INPUT_VEL:
            seen.append((data[:4], t_mono))

    emulator = ODriveEmulator(interface, channel, node_ids=(LEFT_NODE, RIGHT_NODE),
                              bus_kwargs=bus_kwargs)
    emulator.frame_hooks.append(record)
    options: dict[str, Any] = {"interface": interface, "channel": channel,
                               "keepalive_period_s": 0.0}
    if "port" in bus_kwargs:
        options["multicast_port"] = bus_kwargs["port"]
    with emulator:
        driver = ODriveCanDriver(options, max_wheel_speed=40.0)
        await driver.open()
        try:
            to_return, to_odrive = await _time_commands(driver, seen, count)
        finally:
            await driver.close()
    call, wire = summarize(to_return), summarize(to_odrive)
    note = (f"{count} set_wheel_speeds calls; emulator thread in this process on python-can "
            f"{interface}; on a real CAN bus each 8-byte frame adds ~0.25 ms at 500 kbit/s")
    name = f"odrive_can {interface}"
    return [
        BenchResult(SUITE, f"{name} command->sent p50", call["p50"], "ms", note=note),
        BenchResult(SUITE, f"{name} command->sent p99", call["p99"], "ms"),
        BenchResult(SUITE, f"{name} command->ODrive p50", wire["p50"], "ms",
                    note=f"until the emulated ODrive handled the right wheel's Set_Input_Vel "
                         f"({wire['count']} matched)"),
        BenchResult(SUITE, f"{name} command->ODrive p99", wire["p99"], "ms"),
    ]


async def _time_commands(driver: ODriveCanDriver, seen: deque[tuple[bytes, float]],
                         count: int) -> tuple[list[float], list[float]]:
    to_return: list[float] = []
    to_odrive: list[float] = []
    for i in range(count):
        speed = 1.0 + 0.01 * (i % 500)  # distinct values, so each frame can be matched
        start = time.monotonic()
        await driver.set_wheel_speeds(speed, speed)
        to_return.append((time.monotonic() - start) * 1e3)
        # the right motor is mirrored: its frame carries the negated turns per second
        expected = struct.pack("<f", -speed / (2 * 3.141592653589793))
        arrival = await _arrival(seen, expected, start)
        if arrival is not None:
            to_odrive.append((arrival - start) * 1e3)
    return to_return, to_odrive


async def _arrival(seen: deque[tuple[bytes, float]], payload: bytes, since: float,
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
