# Hardware probing for `arbiterd check` and the motor-off path of `arbiterd safe-stop`.
from __future__ import annotations

import asyncio
import sys

from daemon.config import Config, build_driver
from drivers import DriverError
from sensors.rplidar.client import LidarError, RplidarClient, describe, open_serial
from sensors.rplidar.settings import LidarSettings


async def probe_hardware(config: Config) -> list[str]:
    """Open the configured driver and ask a configured lidar; list what failed."""
    problems = []
    driver = build_driver(config)
    try:
        await driver.open()
    except DriverError as exc:
        problems.append(f"[driver] {config['driver']['type']}: {exc}")
    finally:
        await driver.close()
    problems += [f"[lidar] {p}" for p in await probe_lidar(config)]
    problems += await probe_arm(config)
    problems += await probe_battery(config)
    return problems


async def probe_battery(config: Config) -> list[str]:
    """Open the battery monitor (``[battery]`` on), read it once, close it: a missing chip, a
    wrong address, a loose bus wire or a shunt out of range is named."""
    from daemon.components.battery.component import build_monitor
    from daemon.components.battery.settings import BatterySettings

    settings = config.get(BatterySettings)
    if not settings.enabled or settings.device == "sim":
        return []
    try:
        reading = await build_monitor(config).probe()
    except DriverError as exc:
        return [str(exc)]
    print(f"battery: {reading['voltage']:.2f} V, {reading['current']:.3f} A "
          f"({settings.device})", file=sys.stderr)
    return []


async def probe_arm(config: Config) -> list[str]:
    """Ask the arm's servo output (``[arm]`` on) whether it answers, without moving a servo."""
    from daemon.components.arm.component import build_servo

    if not config["arm"]["enabled"]:
        return []
    try:
        await build_servo(config).probe()
    except DriverError as exc:
        return [str(exc)]
    return []


async def safe_stop(config: Config) -> None:
    """Zero the motors through the configured driver, from a process of its own; then put the
    arm's servos (``[arm]`` on) in their shutdown state, even when the wheels failed."""
    try:
        await build_driver(config).safe_stop()
    finally:
        await safe_stop_arm(config)


async def safe_stop_arm(config: Config) -> str | None:
    """``[arm] on_stop``: ``relax`` turns the servo pulses off; ``home`` sends the home pose's
    pulses at once (after a crash nothing knows where the arm is: each servo moves there at
    its own speed). None when the arm is off."""
    from daemon.components.arm.component import build_servo
    from daemon.components.arm.settings import ArmSettings

    settings = config.get(ArmSettings)
    if not settings.enabled:
        return None
    servo = build_servo(config)
    try:
        await servo.open()
        if settings.on_stop == "home":
            await servo.write(settings.named_poses()["home"])
            return "home"
        await servo.relax()
        return "relaxed"
    finally:
        await servo.close()


async def probe_lidar(config: Config) -> list[str]:
    """Ask a configured RPLIDAR for its INFO and HEALTH; list what is wrong."""
    lidar = config.get(LidarSettings)
    if not lidar.enabled:
        return []
    return await asyncio.to_thread(_probe_lidar_blocking, lidar.port, lidar.baudrate)


def _probe_lidar_blocking(port_path: str, baudrate: int) -> list[str]:
    try:
        port = open_serial(port_path, baudrate)
    except LidarError as exc:
        return [f"{port_path}: {exc}"]
    client = RplidarClient(port)
    try:
        client.stop()
        info = client.info()
        health = client.health()
    except LidarError as exc:
        return [f"{port_path}: no answer at {baudrate} baud ({exc})"]
    finally:
        port.close()
    found = describe(info)
    print(f"# lidar: {found['model']} firmware {found['firmware']} on {port_path}, "
          f"health {health.status_name}", file=sys.stderr)
    if health.status == 2:
        return [f"{port_path}: the lidar reports a health error (code {health.error_code:#06x})"]
    return []
