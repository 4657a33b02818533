# Hobby servos on the Pi's GPIO through pigpiod: one pin per named joint, 500-2500 µs pulses.
from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass
from typing import Any, ClassVar

from base.options import Option, Options
from drivers.devices import Actuator, DeviceError, Joint
from drivers.pigpiod_client import connect_pigpio, drop_pigpio
from drivers.pigpiod_watch import describe_io_error

#: the pulse widths pigpio accepts for a servo (0 turns the pulses off)
PULSE_MIN_US, PULSE_MAX_US = 500, 2500


SERVO_OPTIONS: Options = {
    "host": Option(str, "localhost", "pigpiod host"),
    "port": Option(int, 8888, "pigpiod port", minval=1, maxval=65535),
    "joints": Option(list, ["joint1"], "joint names, one per servo", item=str),
    "pins": Option(list, [16], "GPIO (BCM) of each joint's servo signal, in joint order (not "
                   "a pin of the wheel driver's section)",
                   item=int, minval=0, maxval=53),
    "lower": Option(list, [-math.pi / 2], "each joint's lowest position, rad (at "
                    "min_pulse_us)", item=float),
    "upper": Option(list, [math.pi / 2], "each joint's highest position, rad (at "
                    "max_pulse_us)", item=float),
    "min_pulse_us": Option(int, 500, "pulse width at the lowest position, µs",
                           minval=PULSE_MIN_US, maxval=PULSE_MAX_US),
    "max_pulse_us": Option(int, 2500, "pulse width at the highest position, µs",
                           minval=PULSE_MIN_US, maxval=PULSE_MAX_US),
    "timeout_s": Option(float, 1.0, "connecting to and each reply from pigpiod, s",
                        above=0.0, maxval=30.0),
}


@dataclass(frozen=True)
class ServoSettings:
    host: str
    port: int
    joints: list[str]
    pins: list[int]
    lower: list[float]
    upper: list[float]
    min_pulse_us: int
    max_pulse_us: int
    timeout_s: float


def pulse_width(joint: Joint, position: float, min_us: int, max_us: int) -> int:
    """The pulse width (µs) of a position within the joint's limits (linear)."""
    fraction = (position - joint.lower) / (joint.upper - joint.lower)
    return round(min_us + fraction * (max_us - min_us))


def position_of(joint: Joint, pulse_us: int, min_us: int, max_us: int) -> float:
    """The inverse of :func:`pulse_width` (what a servo at that pulse holds)."""
    return joint.lower + (pulse_us - min_us) / (max_us - min_us) * (joint.upper - joint.lower)


class PigpioServos(Actuator):
    """Servos on GPIO pins driven by pigpiod's servo pulses (``set_servo_pulsewidth``)."""

    OPTIONS: ClassVar[Options] = SERVO_OPTIONS
    SETTINGS = ServoSettings

    def __init__(self, options: Any, *, section: str) -> None:
        super().__init__(options, section=section)
        s: ServoSettings = self.settings
        lengths = {len(s.joints), len(s.pins), len(s.lower), len(s.upper)}
        if not s.joints:
            raise ValueError(f"[{section}] joints: name at least one joint")
        if len(lengths) != 1:
            raise ValueError(f"[{section}] joints, pins, lower and upper need one entry per "
                             f"joint (got {len(s.joints)}, {len(s.pins)}, {len(s.lower)}, "
                             f"{len(s.upper)})")
        if len(set(s.pins)) != len(s.pins):
            raise ValueError(f"[{section}] pins: a GPIO is used twice: {s.pins}")
        if s.min_pulse_us >= s.max_pulse_us:
            raise ValueError(f"[{section}] min_pulse_us must be below max_pulse_us")
        for name, low, high in zip(s.joints, s.lower, s.upper, strict=True):
            if not low < high:
                raise ValueError(f"[{section}] joint {name}: lower ({low}) must be below "
                                 f"upper ({high})")
        self._joints = tuple(Joint(n, lo, hi) for n, lo, hi in
                             zip(s.joints, s.lower, s.upper, strict=True))
        self._pins = dict(zip(s.joints, s.pins, strict=True))
        self._pi: Any = None

    def joints(self) -> tuple[Joint, ...]:
        return self._joints

    async def _open(self) -> None:
        s: ServoSettings = self.settings
        try:
            self._pi = await asyncio.to_thread(connect_pigpio, s.host, s.port, s.timeout_s)
        except Exception as exc:
            raise DeviceError(f"[{self.section}] {exc}") from None

    async def _write(self, targets: dict[str, float]) -> None:
        s: ServoSettings = self.settings
        by_name = {joint.name: joint for joint in self._joints}
        pulses = {self._pins[name]: pulse_width(by_name[name], value, s.min_pulse_us,
                                                 s.max_pulse_us)
                  for name, value in targets.items()}
        await self._send(pulses)

    async def _relax(self) -> None:
        await self._send(dict.fromkeys(self._pins.values(), 0))

    async def _send(self, pulses: dict[int, int]) -> None:
        pi = self._pi

        def send() -> None:
            for pin, pulse in pulses.items():
                result = pi.set_servo_pulsewidth(pin, pulse)
                if isinstance(result, int) and result < 0:
                    raise DeviceError(f"[{self.section}] pigpiod refused GPIO {pin} pulse "
                                      f"{pulse} µs (error {result})")

        try:
            await asyncio.to_thread(send)
        except DeviceError:
            raise
        except Exception as exc:
            raise DeviceError(f"[{self.section}] {describe_io_error(exc)}") from None

    async def _close(self) -> None:
        pi, self._pi = self._pi, None
        if pi is not None:
            await asyncio.to_thread(drop_pigpio, pi, peer_alive=self.fault is None)
