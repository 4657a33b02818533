# How far the robot rolls while the daemon is frozen (SIGSTOP): per driver, device in this process.
from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.config import load_config
from sim.motor_model import MotorPair
from sim.wiring import EMULATORS, Emulated, mounted

#: drivers whose device can live in another process than the daemon (the mock has none; the
#: ODrive is reached over python-can's udp_multicast interface)
DRIVERS = ("serial", "pigpio", "l298n", "odrive_can")
#: the options that switch each device's deadman off (--no-deadman)
NO_DEADMAN: dict[str, dict[str, Any]] = {"pigpio": {"deadman_s": 0.0},
                                         "odrive_can": {"watchdog_timeout_s": 0.0}}
WHEEL_RADIUS = 0.05  # [robot] default
SPEED_M_S = 0.5


@dataclass(frozen=True)
class Roll:
    """One measurement: the driver, its device deadman, the speed, and the distance the
    wheels (ground truth, in the device's process) rolled while the daemon was stopped."""

    driver: str
    deadman: str
    speed_m_s: float
    frozen_s: float
    rolled_m: float
    still_after_s: float | None


def deadman_of(driver: str, options: dict[str, Any]) -> str:
    if driver == "serial":
        return f"firmware auto-stop {options['auto_stop_s']:g} s"
    if driver == "pigpio":
        return f"pigpiod script {options['deadman_s']:g} s" if options["deadman_s"] else "none"
    if driver == "odrive_can":
        watchdog = options["watchdog_timeout_s"]
        return f"ODrive axis watchdog {watchdog:g} s" if watchdog else "none"
    return "none"


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _post(url: str, body: dict[str, Any]) -> None:
    request = urllib.request.Request(url, json.dumps(body).encode(),
                                     {"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=2.0) as reply:
        reply.read()


def _healthy(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=1.0) as reply:
            return bool(reply.status == 200)
    except OSError:
        return False


@contextmanager
def device(driver: str, workdir: Path, overrides: dict[str, Any]) -> Iterator[
        tuple[MotorPair, Emulated, dict[str, Any]]]:
    """The driver's emulated device, running in this process on real-time wheels."""
    config = load_config(None, sim=True, env={})
    config.update(f"driver.{driver}", overrides)
    options = config.driver_options(driver)
    wiring = EMULATORS[driver]
    pair = wiring.motors(max_speed_rad_s=40.0, time_constant_s=0.05)
    emulated = _odrive(pair, options) if driver == "odrive_can" else \
        wiring.start(pair, workdir, options, ())
    try:
        yield pair, emulated, {**options, **emulated.options}
    finally:
        emulated.stop()


def _odrive(pair: MotorPair, options: dict[str, Any]) -> Emulated:
    """An ODrive on udp_multicast (a virtual channel does not leave the process), its axes
    mounted as the section expects (as sim.wiring does)."""
    from sim.odrive_emulator import DEFAULT_MULTICAST_GROUP, ODriveEmulator

    pair.wiring = mounted(options)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("", 0))
        port = int(sock.getsockname()[1])
    odrive = ODriveEmulator("udp_multicast", DEFAULT_MULTICAST_GROUP, motors=pair,
                            directions=(1, 1), node_ids=(options["left_node_id"],
                                                         options["right_node_id"]),
                            gear_ratio=options["gear_ratio"],
                            watchdog_timeout_s=options["watchdog_timeout_s"],
                            bus_kwargs={"port": port}).start()
    reach = {"interface": "udp_multicast", "channel": DEFAULT_MULTICAST_GROUP,
             "multicast_port": port}
    return Emulated(odrive, reach, odrive.stop)


def _config(driver: str, options: dict[str, Any], port: int, workdir: Path) -> Path:
    lines = ["[driver]", f'type = "{driver}"', f"[driver.{driver}]"]
    lines += [f"{key} = {json.dumps(value)}" for key, value in options.items()
              if key in _driver_keys(driver)]
    lines += ["[lidar]", "enabled = false", "[http]", 'host = "127.0.0.1"', f"port = {port}",
              "[rosbridge]", 'host = "127.0.0.1"', f"port = {_free_port()}"]
    path = workdir / "frozen.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def _driver_keys(driver: str) -> set[str]:
    from drivers import driver_class

    return set(driver_class(driver).OPTIONS)


def _travel(pair: MotorPair) -> float:
    left, right = pair.positions()
    return (left + right) / 2.0 * WHEEL_RADIUS


def measure(driver: str, frozen_s: float = 3.0, overrides: dict[str, Any] | None = None,
            speed: float = SPEED_M_S) -> Roll:
    """Start `arbiterd run` on ``driver`` against its emulated device in this process, drive
    at ``speed``, SIGSTOP the daemon for ``frozen_s`` and read how far the wheels rolled."""
    with tempfile.TemporaryDirectory(prefix="arbiterd-frozen-") as tmp, \
            device(driver, Path(tmp), overrides or {}) as (pair, _, options):
        port = _free_port()
        path = _config(driver, options, port, Path(tmp))
        base = f"http://127.0.0.1:{port}"
        proc = subprocess.Popen([sys.executable, "-m", "daemon.cli", "run", "--config",
                                 str(path)], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, env={**os.environ})
        try:
            return _drive_and_freeze(proc, base, pair, driver, options, frozen_s, speed)
        finally:
            os.kill(proc.pid, signal.SIGCONT)
            proc.terminate()
            proc.wait(timeout=10)


def _drive_and_freeze(proc: subprocess.Popen[bytes], base: str, pair: MotorPair, driver: str,
                      options: dict[str, Any], frozen_s: float, speed: float) -> Roll:
    deadline = time.monotonic() + 30.0
    while not _healthy(f"{base}/api/health"):
        if time.monotonic() > deadline or proc.poll() is not None:
            raise RuntimeError(f"arbiterd run on {driver} did not come up")
        time.sleep(0.1)
    until = time.monotonic() + 1.5
    while time.monotonic() < until:  # a teleop at 10 Hz until the wheels are at speed
        _post(f"{base}/api/cmd_vel", {"linear": {"x": speed}})
        time.sleep(0.1)
    os.kill(proc.pid, signal.SIGSTOP)
    start, t0 = _travel(pair), time.monotonic()
    still_at: float | None = None
    last = start
    while time.monotonic() - t0 < frozen_s:
        time.sleep(0.02)
        now = _travel(pair)
        if abs(now - last) < 1e-5:
            still_at = still_at if still_at is not None else time.monotonic() - t0
        else:
            still_at = None
        last = now
    rolled = _travel(pair) - start
    os.kill(proc.pid, signal.SIGCONT)
    return Roll(driver, deadman_of(driver, options), speed, frozen_s, rolled,
                None if still_at is None else round(still_at, 2))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__ or "frozen-daemon roll per driver")
    parser.add_argument("--driver", action="append", choices=DRIVERS)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--speed", type=float, default=SPEED_M_S)
    parser.add_argument("--no-deadman", action="store_true",
                        help="pigpio deadman_s = 0, odrive_can watchdog_timeout_s = 0: the "
                        "devices without their deadman")
    args = parser.parse_args(argv)
    print("| driver | device deadman | speed | rolled in the frozen time | still after |")
    print("|---|---|---|---|---|")
    for driver in args.driver or DRIVERS:
        overrides = NO_DEADMAN.get(driver, {}) if args.no_deadman else {}
        roll = measure(driver, args.seconds, overrides, args.speed)
        still = "moving" if roll.still_after_s is None else f"{roll.still_after_s:.2f} s"
        print(f"| {roll.driver} | {roll.deadman} | {roll.speed_m_s:g} m/s | "
              f"{roll.rolled_m:.3f} m in {roll.frozen_s:g} s | {still} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
