# Test rigs: every registered driver against its emulator (sim/wiring.py), plus test-only variants.
from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from functools import partial
from pathlib import Path
from typing import Any

import serial

from base.options import defaults
from drivers import DRIVERS, MotorDriver, create_driver, driver_class
from drivers.rosarduino import BAUDRATE, MOTOR_SPEEDS, OK, encode_command
from sim.motor_model import MotorPair
from sim.wiring import EMULATORS, Emulated
from tests.support.mock_wheel_log import read_wheel_log
from tests.support.wait import eventually

#: Wheel speed at full duty of the PWM rigs' motors, rad/s (the driver's duty map says the same).
FULL_DUTY_SPEED = 20.0

#: Test-only options per driver, on top of the defaults and under a test's own overrides: quick
#: fault detection, and odrive node ids that are not the defaults (so they are really read).
RIG_OPTIONS: dict[str, dict[str, Any]] = {
    "mock": {},
    "serial": {"timeout_s": 1.0},
    "pigpio": {"watch_interval": 0.05, "timeout": 0.5},
    "l298n": {"watch_interval": 0.05, "timeout": 0.5},
    "odrive_can": {"left_node_id": 3, "right_node_id": 4},
}
#: Wheel saturation speed of each rig's motors, rad/s (PWM drivers: the full-duty speed).
MOTOR_MAX_SPEED = {"pigpio": FULL_DUTY_SPEED, "l298n": FULL_DUTY_SPEED}

Cleanup = Callable[[], Awaitable[None]]


async def nothing_to_clean() -> None:
    """The clean-up of a strand that left nothing behind."""


class Rig:
    """A driver's emulated hardware, running, and the ``[driver.<name>]`` options reaching it.

    ``motors`` is the emulator's :class:`sim.motor_model.MotorPair` (what the hardware does);
    ``emulator`` the emulator itself, for fault switches; ``quantum_rad_s`` the smallest speed
    step the wire carries; ``reachable_from_other_processes`` whether a daemon subprocess can
    reach the emulator (a python-can virtual bus or gpiozero's mock pins cannot be).
    """

    @classmethod
    def own_options(cls, workdir: Path) -> dict[str, Any]:
        """Options this kind of rig needs besides the emulator's."""
        return {}

    def __init__(self, driver_name: str, options: dict[str, Any], motors: MotorPair,
                 emulated: Emulated) -> None:
        self.driver_name = driver_name
        self.options = options
        self.motors = motors
        self.emulator: Any = emulated.emulator
        self.quantum_rad_s = emulated.resolution_rad_s
        self.reachable_from_other_processes = not emulated.in_process_only

    def observed_targets(self) -> tuple[float, float]:
        """Wheel speed set-points (rad/s, forward positive) the emulated hardware last received."""
        return self.motors.targets()

    def make_driver(self, max_wheel_speed: float, **overrides: Any) -> MotorDriver:
        """A fresh driver on this rig's options (plus ``overrides``), not opened."""
        return create_driver(self.driver_name, self.options | overrides,
                             max_wheel_speed=max_wheel_speed)

    async def strand(self, speed_rad_s: float = 10.0) -> Cleanup:
        """Leave the wheels turning as a daemon that hung mid-drive would: a driver that
        commanded ``speed_rad_s`` and holds the hardware until the returned clean-up."""
        hung = self.make_driver(40.0)
        await hung.open()
        await hung.set_wheel_speeds(speed_rad_s, speed_rad_s)
        return hung.close


class MockRig(Rig):
    """The mock driver logs every command to a file: that log is what its "hardware" saw (from
    any process)."""

    @classmethod
    def own_options(cls, workdir: Path) -> dict[str, Any]:
        return {"log_file": str(workdir / "mock-wheels.log")}

    def observed_targets(self) -> tuple[float, float]:
        rows = read_wheel_log(Path(self.options["log_file"]))
        return (rows[-1][1], rows[-1][2]) if rows else (0.0, 0.0)


class SerialRig(Rig):
    """The emulated Arduino; the driver opens its port exclusively."""

    async def strand(self, speed_rad_s: float = 10.0) -> Cleanup:
        """A board that neither resets on open nor auto-stops soon, left driving by a daemon
        that wrote one motor command and died (the port is free again)."""
        self.emulator.reset_on_open = False
        self.emulator.firmware.auto_stop_s = 120.0
        ticks = round(speed_rad_s / self.quantum_rad_s)
        with serial.Serial(self.options["port"], BAUDRATE, timeout=1) as port:
            port.write(encode_command(MOTOR_SPEEDS, ticks, ticks))
            assert port.readline().strip() == OK.encode()
        return nothing_to_clean


def section(driver_name: str, overrides: dict[str, Any]) -> dict[str, Any]:
    """A complete ``[driver.<name>]`` section: defaults, the rig's options, ``overrides``."""
    return defaults(driver_class(driver_name).OPTIONS) | RIG_OPTIONS[driver_name] | overrides


def rig_motors(driver_name: str) -> MotorPair:
    """Real-time motors with the driver's agreed encoder resolution."""
    wiring = EMULATORS[driver_name]
    return wiring.motors(max_speed_rad_s=MOTOR_MAX_SPEED.get(driver_name, 40.0))


@contextmanager
def wired_rig(driver_name: str, workdir: Path, motors: MotorPair | None = None,
              **overrides: Any) -> Iterator[Rig]:
    """The driver's emulator from ``sim.wiring.EMULATORS``, as the simulator starts it."""
    motors = motors or rig_motors(driver_name)
    kind = RIG_KINDS.get(driver_name, Rig)
    options = section(driver_name, kind.own_options(workdir) | overrides)
    emulated = EMULATORS[driver_name].start(motors, workdir, options)
    try:
        yield kind(driver_name, options | emulated.options, motors, emulated)
    finally:
        emulated.stop()


async def restart_pigpiod_and_reopen(rig: Rig, driver: MotorDriver) -> None:
    """With pigpiod down and ``driver`` closed: the wheels coast to a stop, pigpiod restarts,
    the driver reconnects (its second connect) and the wheels stay still until a fresh
    command."""
    await eventually(lambda: all(abs(v) < 1e-3 for v in rig.motors.speeds()),
                     "the wheels to coast to a stop while pigpiod is down")
    rig.emulator.start()
    await driver.open()
    assert driver.health()["status"] == "ok" and driver.health()["connects"] == 2
    await asyncio.sleep(0.1)
    assert rig.observed_targets() == (0.0, 0.0)  # still until a fresh command


RIG_KINDS: dict[str, type[Rig]] = {"mock": MockRig, "serial": SerialRig}
RigFactory = Callable[..., AbstractContextManager[Rig]]


def _rigs() -> dict[str, RigFactory]:
    from tests.support.rigs.l298n import mock_pin_rig

    table: dict[str, RigFactory] = {name: partial(wired_rig, name) for name in DRIVERS}
    table["l298n@pigpio"] = table["l298n"]  # the l298n driver through the emulated pigpiod
    table["l298n"] = mock_pin_rig  # and through gpiozero's MockFactory pins
    return table


#: rig name => factory ``(workdir, motors=None, **overrides)`` of a context manager yielding
#: a :class:`Rig`: every registered driver, plus the ``l298n@pigpio`` variant.
RIGS: dict[str, RigFactory] = _rigs()

__all__ = ["FULL_DUTY_SPEED", "RIGS", "Cleanup", "MockRig", "Rig", "RigFactory", "SerialRig",
           "nothing_to_clean", "restart_pigpiod_and_reopen", "rig_motors", "section", "wired_rig"]
