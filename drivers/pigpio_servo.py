# Hobby servos on the Pi's GPIO through pigpiod: one pin per named joint, 500-2500 µs pulses.
from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import Any, ClassVar

from base.options import Option, Options
from drivers.devices import DeviceError
from drivers.pigpiod_client import connect_pigpio, drop_pigpio
from drivers.pigpiod_watch import describe_io_error
from drivers.servo_array import CALIBRATION_OPTIONS, CalibrationSettings, ServoArray

SERVO_OPTIONS: Options = {
    "host": Option(str, "localhost", "pigpiod host"),
    "port": Option(int, 8888, "pigpiod port", minval=1, maxval=65535),
    "pins": Option(list, [16], "GPIO (BCM) of each joint's servo signal, in joint order (not "
                   "a pin of the wheel driver's section)",
                   item=int, minval=0, maxval=53),
    **CALIBRATION_OPTIONS,
    "timeout_s": Option(float, 1.0, "connecting to and each reply from pigpiod, s",
                        above=0.0, maxval=30.0),
}


@dataclass(frozen=True)
class ServoSettings(CalibrationSettings):
    host: str
    port: int
    pins: list[int]
    timeout_s: float


class PigpioServos(ServoArray):
    """Servos on GPIO pins driven by pigpiod's servo pulses (``set_servo_pulsewidth``)."""

    OPTIONS: ClassVar[Options] = SERVO_OPTIONS
    SETTINGS = ServoSettings
    OUTPUTS_KEY = "pins"
    OUTPUT_NOUN = "a GPIO"

    def __init__(self, options: Any, *, section: str) -> None:
        super().__init__(options, section=section)
        self._pi: Any = None

    async def _open(self) -> None:
        s: ServoSettings = self.settings
        try:
            self._pi = await asyncio.to_thread(connect_pigpio, s.host, s.port, s.timeout_s)
        except Exception as exc:
            raise DeviceError(f"[{self.section}] {exc}") from None

    async def _send_pulses(self, pulses: dict[int, float]) -> None:
        await self._send({pin: round(pulse) for pin, pulse in pulses.items()})

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
