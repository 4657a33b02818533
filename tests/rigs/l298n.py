# Rigs for the l298n driver: gpiozero's MockFactory pins, and PiGPIOFactory on the pigpiod emulator.
from __future__ import annotations

import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from drivers.l298n import L298NDriver, mock_pin_factory
from sim.motor_model import MotorPair
from sim.pigpiod_emulator import (
    PigpiodEmulator,
    Wiring,
    default_motors,
    l298n_driver_wiring,
    quadrature_levels,
)

#: Wheel speed at full duty in the emulated motors and the driver's map (rad/s).
FULL_DUTY_SPEED = 20.0
#: Encoder edges per wheel revolution in the emulated hardware (modest: sane edge rates).
EDGES_PER_REV = 200
#: What gpiozero's RotaryEncoder counts for that: one step per 4-edge quadrature cycle.
STEPS_PER_REV = EDGES_PER_REV // 4


def base_options(**overrides: Any) -> dict[str, Any]:
    return {
        "max_wheel_speed": FULL_DUTY_SPEED,
        "encoders": True,
        "encoder_counts_per_rev": STEPS_PER_REV,
        "watch_interval": 0.05,
        "timeout": 0.5,
    } | overrides


def wiring_for(options: dict[str, Any], *, reverse: tuple[bool, bool] = (False, False)) -> Wiring:
    """The hardware that matches a ``[driver.l298n]`` section: IN1/IN2 PWM, EN if wired."""
    opts = {k: o.default for k, o in L298NDriver.OPTIONS.items()} | options
    return l298n_driver_wiring(opts, reverse)


class MockPinBridge:
    """The L298N, motors and encoders behind gpiozero mock pins.

    A thread polls the bridge pins into MotorPair duties and walks the encoder input pins one
    quadrature edge at a time as the MotorPair counts change (``drive_high``/``drive_low``
    fire gpiozero's callbacks, as a real edge would).
    """

    def __init__(self, factory: Any, wiring: Wiring, motors: MotorPair,
                 poll_s: float = 0.002) -> None:
        self.factory, self.wiring, self.motors, self.poll_s = factory, wiring, motors, poll_s
        self._counts = list(motors.counts())
        for side in (wiring.left, wiring.right):  # create every pin up front, in this thread
            for gpio in side.pins():
                factory.pin(gpio)
        for _, pins in wiring.encoders():
            for gpio in pins:
                factory.pin(gpio)
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._run, name="mock-l298n", daemon=True)

    def level(self, gpio: int) -> float:
        return float(self.factory.pin(gpio).state)

    def duties(self) -> tuple[float, float]:
        return self.wiring.left.duty(self.level), self.wiring.right.duty(self.level)

    def start(self) -> MockPinBridge:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._halt.set()
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        while not self._halt.wait(self.poll_s):
            self.motors.set_duties(*self.duties())
            self._step_encoders(self.motors.counts())

    def _step_encoders(self, counts: tuple[int, int]) -> None:
        for side, (pin_a, pin_b) in self.wiring.encoders():
            while self._counts[side] != counts[side]:
                self._counts[side] += 1 if counts[side] > self._counts[side] else -1
                for gpio, level in zip((pin_a, pin_b), quadrature_levels(self._counts[side]),
                                       strict=True):
                    pin = self.factory.pin(gpio)
                    if pin.function == "input":
                        pin.drive_high() if level else pin.drive_low()


class L298NMockRig:
    """gpiozero's mock pins: what the driver drives is read off the pins themselves."""

    driver_name = "l298n"

    def __init__(self, options: dict[str, Any], bridge: MockPinBridge) -> None:
        self.options = options
        self.bridge = bridge
        self.motors = bridge.motors
        self.wheel_sign = 1.0

    def observed_targets(self) -> tuple[float, float]:
        left, right = self.bridge.duties()
        return left * FULL_DUTY_SPEED, right * FULL_DUTY_SPEED


class L298NPigpioRig:
    """PiGPIOFactory on the pigpiod emulator: what the driver drives arrives as socket bytes."""

    driver_name = "l298n"

    def __init__(self, options: dict[str, Any], emulator: PigpiodEmulator) -> None:
        self.options = options
        self.emulator = emulator
        self.motors = emulator.motors
        self.wheel_sign = 1.0

    def observed_targets(self) -> tuple[float, float]:
        return self.motors.targets()


@asynccontextmanager
async def mock_rig(motors: MotorPair | None = None, *, reverse: tuple[bool, bool] = (False, False),
                   **overrides: Any) -> AsyncIterator[L298NMockRig]:
    options = base_options(pin_factory="mock", **overrides)
    factory = mock_pin_factory()
    factory.reset()
    bridge = MockPinBridge(factory, wiring_for(options, reverse=reverse),
                           motors or default_motors(EDGES_PER_REV, FULL_DUTY_SPEED)).start()
    try:
        yield L298NMockRig(options, bridge)
    finally:
        bridge.stop()
        factory.reset()


@asynccontextmanager
async def pigpio_rig(motors: MotorPair | None = None, *,
                     reverse: tuple[bool, bool] = (False, False),
                     **overrides: Any) -> AsyncIterator[L298NPigpioRig]:
    options = base_options(pin_factory="pigpio", pigpio_host="127.0.0.1", **overrides)
    emulator = PigpiodEmulator(wiring_for(options, reverse=reverse),
                               motors or default_motors(EDGES_PER_REV, FULL_DUTY_SPEED)).start()
    options["pigpio_port"] = emulator.port
    try:
        yield L298NPigpioRig(options, emulator)
    finally:
        emulator.close()


@asynccontextmanager
async def rig(tmp_path: Path) -> AsyncIterator[L298NMockRig]:
    """The l298n driver through gpiozero's MockFactory."""
    async with mock_rig() as the_rig:
        yield the_rig


@asynccontextmanager
async def rig_pigpio(tmp_path: Path) -> AsyncIterator[L298NPigpioRig]:
    """The l298n driver through gpiozero's PiGPIOFactory on the pigpiod emulator."""
    async with pigpio_rig() as the_rig:
        yield the_rig
