# The l298n driver on gpiozero's MockFactory pins: a rig of its own (no pigpiod in between).
from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from drivers.l298n import mock_pin_factory
from drivers.quadrature import quadrature_levels
from sim.motor_model import MotorPair
from sim.pigpiod_emulator import Wiring, l298n_driver_wiring
from sim.wiring import EMULATORS, Emulated, mounted
from tests.support.rigs import FULL_DUTY_SPEED, Cleanup, Rig, nothing_to_clean, rig_motors, section


class MockPinBridge:
    """The L298N, motors and encoders behind gpiozero mock pins.

    A thread polls the bridge pins into MotorPair duties and walks the encoder input pins one
    quadrature edge at a time as the MotorPair counts change (``drive_high``/``drive_low``
    fire gpiozero's callbacks, as a real edge would).
    """

    def __init__(self, factory: Any, wiring: Wiring, motors: MotorPair,
                 poll_s: float = 0.002) -> None:
        assert wiring.left is not None and wiring.right is not None, "an L298N on both sides"
        self.factory, self.motors, self.poll_s = factory, motors, poll_s
        self.wiring, self.left, self.right = wiring, wiring.left, wiring.right
        self._counts = list(motors.counts())
        for side in (self.left, self.right):  # create every pin up front, in this thread
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
        return self.left.duty(self.level), self.right.duty(self.level)

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


class MockPinRig(Rig):
    """What the driver drives is read off gpiozero's mock pins themselves."""

    def __init__(self, options: dict[str, Any], bridge: MockPinBridge) -> None:
        super().__init__("l298n", options, bridge.motors,
                         Emulated(bridge, {}, bridge.stop, in_process_only=True))
        self.bridge = bridge

    def observed_targets(self) -> tuple[float, float]:
        left, right = self.motors.wiring.wheel_duties(*self.bridge.duties())
        return left * FULL_DUTY_SPEED, right * FULL_DUTY_SPEED

    async def strand(self, speed_rad_s: float = 10.0) -> Cleanup:
        """Forward PWM on both sides, as a dead daemon left the pins (a second driver could
        not claim pins the first still holds)."""
        for gpio in (self.options["left_forward"], self.options["right_forward"]):
            pin = self.bridge.factory.pin(gpio)
            pin.function, pin.frequency = "output", 500
            pin.state = min(1.0, speed_rad_s / FULL_DUTY_SPEED)
        return nothing_to_clean


@contextmanager
def mock_pin_rig(workdir: Path | None = None, motors: MotorPair | None = None,
                 **overrides: Any) -> Iterator[MockPinRig]:
    """The l298n driver through ``pin_factory = "mock"``, encoders on, at the agreed
    resolution (RotaryEncoder steps are 4-edge quadrature cycles)."""
    steps = EMULATORS["l298n"].counts_per_rev // 4
    options = section("l298n", {"pin_factory": "mock", "max_wheel_speed": FULL_DUTY_SPEED,
                                "encoders": True, "encoder_counts_per_rev": steps} | overrides)
    factory = mock_pin_factory()
    factory.reset()
    motors = motors or rig_motors("l298n")
    motors.wiring = mounted(options)
    bridge = MockPinBridge(factory, l298n_driver_wiring(options), motors).start()
    try:
        yield MockPinRig(options, bridge)
    finally:
        bridge.stop()
        factory.reset()
