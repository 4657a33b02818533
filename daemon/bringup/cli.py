# `arbiterd test-motors [--config PATH] [--sim] [--yes] [--json]`: who watches, on what hardware.
from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from daemon.bringup import motors
from daemon.bringup.motors import NO_HAND_TURN, SIDES
from daemon.config import Config, ConfigError, build_driver
from daemon.settings import DriverSettings, RobotSettings
from drivers import DriverError
from sim.motor_model import MotorPair

EXIT_OK, EXIT_FOUND, EXIT_HARDWARE, EXIT_CONFIG = 0, 1, 69, 78
WARNING = ("test-motors spins each wheel slowly for about a second, then both together.\n"
           "Lift the robot so that both wheels turn freely.")


class SimObserver:
    """The simulation turns the emulated wheels by hand and sees their true motion."""

    def __init__(self, pair: MotorPair) -> None:
        self.pair = pair
        self._before = (0.0, 0.0)

    def turn_by_hand(self, side: str) -> bool:
        self.pair.turn_by_hand(SIDES.index(side), 2 * math.pi)
        return True

    def watch(self, side: str) -> None:
        self._before = self.pair.positions()

    def watched(self, side: str) -> int | None:
        index = SIDES.index(side)
        moved = self.pair.positions()[index] - self._before[index]
        return 0 if abs(moved) < 0.05 else (1 if moved > 0 else -1)


class PersonObserver:
    """A person at the terminal turns the wheels by hand or says which way they turned."""

    def __init__(self, hand_turns: bool) -> None:
        self.hand_turns = hand_turns

    def turn_by_hand(self, side: str) -> bool:
        answer = _ask(f"Mark the {side.upper()} tyre, turn the wheel FORWARD by hand exactly one "
                      "revolution, then press Enter (s to skip): ")
        return answer not in ("s", "skip")

    def watch(self, side: str) -> None:
        if not self.hand_turns:
            print(f"Watch the {side.upper()} wheel now.", file=sys.stderr)

    def watched(self, side: str) -> int | None:
        if self.hand_turns:
            return None
        answer = _ask(f"Which way did the {side.upper()} wheel turn: [f]orward, [b]ackward, "
                      "[n]ot at all? ")
        return {"f": 1, "b": -1, "n": 0}.get(answer[:1])


class NobodyObserver:
    """No terminal: nothing is turned by hand and nobody watches."""

    def turn_by_hand(self, side: str) -> bool:
        return False

    def watch(self, side: str) -> None:
        pass

    def watched(self, side: str) -> int | None:
        return None


def _ask(question: str) -> str:
    print(question, end="", file=sys.stderr, flush=True)
    line = sys.stdin.readline()
    return line.strip().lower()


def confirmed() -> bool:
    print(WARNING, file=sys.stderr)
    return _ask("Are both wheels off the ground? [y/N] ") in ("y", "yes")


@contextlib.contextmanager
def simulated_hardware(config: Config) -> Iterator[MotorPair]:
    """The emulator of ``[sim] driver`` on free-turning wheels (no world: they are off the
    ground), with ``[sim] miswire`` played; the config's driver is pointed at it."""
    from sim.settings import SimConfig, SimSettings
    from sim.wiring import EMULATORS

    sim = SimConfig.from_settings(config.get(SimSettings))
    wiring = EMULATORS[sim.driver]
    pair = wiring.motors(max_speed_rad_s=sim.motor_max_speed,
                         time_constant_s=sim.motor_time_constant)
    workdir = Path(tempfile.mkdtemp(prefix="arbiterd-test-motors-"))
    emulated = wiring.start(pair, workdir, config.driver_options(sim.driver), sim.miswire)
    try:
        config.update("driver", {"type": sim.driver})
        config.update(f"driver.{sim.driver}", emulated.options)
        yield pair
    finally:
        emulated.stop()
        shutil.rmtree(workdir, ignore_errors=True)


async def _test(config: Config, observer: motors.Observer,
                pair: MotorPair | None) -> dict[str, Any]:
    driver = build_driver(config)
    if pair is not None and driver.name() == "mock":
        driver.listeners.append(pair.set_targets)  # type: ignore[attr-defined]
    await driver.open()
    try:
        return await motors.run(driver, config.driver_options(), observer,
                                config.get(RobotSettings).wheel_radius)
    finally:
        await driver.close()


def _observer(config: Config, pair: MotorPair | None) -> motors.Observer:
    if pair is not None:
        return SimObserver(pair)
    if sys.stdin.isatty():
        return PersonObserver(config.get(DriverSettings).type not in NO_HAND_TURN)
    return NobodyObserver()


def test_motors(config: Config, args: argparse.Namespace) -> int:
    """Run the test on the configured (or simulated) hardware; print the report."""
    if not args.yes and not confirmed():
        print("arbiterd test-motors: not confirmed; lift the wheels and run it again (or pass "
              "--yes)", file=sys.stderr)
        return EXIT_FOUND
    try:
        with simulated_hardware(config) if config.sim else contextlib.nullcontext() as pair:
            result = asyncio.run(_test(config, _observer(config, pair), pair))
    except ConfigError:
        raise
    except (DriverError, OSError) as exc:
        print(f"arbiterd test-motors: the {config['driver']['type']} driver: {exc}",
              file=sys.stderr)
        return EXIT_HARDWARE
    print(json.dumps(result) if args.json else motors.render(result))
    return EXIT_OK if result["ok"] else EXIT_FOUND
