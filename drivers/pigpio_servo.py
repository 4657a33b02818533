# Hobby servos on the Pi's GPIO through pigpiod: one pin per named joint, 500-2500 µs pulses.
from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import Any

from base.options import option
from drivers.devices import DeviceError
from drivers.pigpiod_client import connect_pigpio, drop_pigpio
from drivers.pigpiod_watch import describe_io_error
from drivers.servo_array import CalibrationSettings, ServoArray


@dataclass(frozen=True)
class ServoSettings(CalibrationSettings):
    """A pigpio_servo device's keys: pigpiod's address and each joint's GPIO."""

    host: str = option("localhost", "pigpiod host")
    port: int = option(8888, "pigpiod port", minval=1, maxval=65535)
    pins: list[int] = option([16], "GPIO (BCM) of each joint's servo signal, in joint order (not "
                             "a pin of the wheel driver's section)", minval=0, maxval=53)
    timeout_s: float = option(1.0, "connecting to and each reply from pigpiod, s", above=0.0,
                              maxval=30.0)


class PigpioServos(ServoArray):
    """Servos on GPIO pins driven by pigpiod's servo pulses (``set_servo_pulsewidth``)."""

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
