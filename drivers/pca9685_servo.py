# Hobby servos on a PCA9685 16-channel PWM board over I²C (smbus2): one channel per named joint.
from __future__ import annotations

import asyncio
import errno
import threading
import time
from dataclasses import dataclass
from typing import Any

from base.options import option
from drivers import pca9685_protocol as chip
from drivers.devices import DeviceError
from drivers.i2c_link import I2cBus, check_bus, open_i2c
from drivers.servo_array import CalibrationSettings, ServoArray
from drivers.servo_pulses import SERVO_HZ

#: the oscillator needs 500 µs after SLEEP is cleared before RESTART (datasheet §7.3.1.1)
WAKE_S = 0.0005

@dataclass(frozen=True)
class Pca9685Settings(CalibrationSettings):
    """A pca9685_servo device's keys: the board's bus and address, each joint's channel."""

    bus: str = option("/dev/i2c-1", "the I2C bus: /dev/i2c-N (or N); the simulator writes "
                      "emulated:HOST:PORT", check=check_bus)
    address: int = option(chip.DEFAULT_ADDRESS, "the board's I2C address (0x40 with A0..A5 "
                          "open)", minval=0x03, maxval=0x77)
    channels: list[int] = option([0], "each joint's PCA9685 channel (0..15), in joint order",
                                 minval=0, maxval=chip.CHANNELS - 1)
    frequency_hz: float = option(SERVO_HZ, "PWM frequency, Hz (hobby servos: 50)", minval=24.0,
                                 maxval=1526.0)
    timeout_s: float = option(1.0, "each transfer on an emulated bus, s", above=0.0,
                              maxval=30.0)


class Pca9685Servos(ServoArray):
    """Servos on a PCA9685's channels. ``open`` puts the chip to sleep, writes PRESCALE for
    ``frequency_hz`` (it takes it only asleep), wakes it with register auto-increment and
    restarts the PWM; each pulse is one LEDn block write (ON = 0, OFF = the pulse's counts);
    ``relax`` sets each channel's full-off bit."""

    SETTINGS = Pca9685Settings
    OUTPUTS_KEY = "channels"
    OUTPUT_NOUN = "a channel"

    def __init__(self, options: Any, *, section: str) -> None:
        super().__init__(options, section=section)
        s: Pca9685Settings = self.settings
        self.prescale = chip.prescale_for(s.frequency_hz)
        #: the frequency the chip really runs at (PRESCALE is whole)
        self.frequency_hz = chip.frequency_of(self.prescale)
        self._bus: I2cBus | None = None
        self._lock = threading.Lock()

    def _where(self) -> str:
        s: Pca9685Settings = self.settings
        return f"PCA9685 at 0x{s.address:02x} on {s.bus}"

    def _fail(self, exc: OSError) -> DeviceError:
        if exc.errno in (errno.EREMOTEIO, errno.ENXIO, errno.EIO):
            return DeviceError(f"[{self.section}] no answer from the {self._where()} "
                               f"({exc.strerror or exc}): check its wiring and address")
        if exc.errno == errno.ENOENT:
            return DeviceError(f"[{self.section}] {self._where()}: no such bus: enable I2C "
                               "(raspi-config: Interface options, I2C) or fix [arm] bus")
        return DeviceError(f"[{self.section}] {self._where()}: {exc}")

    async def _open(self) -> None:
        try:
            await asyncio.to_thread(self._start_chip)
        except OSError as exc:
            await asyncio.to_thread(self._drop)
            raise self._fail(exc) from None
        except ImportError as exc:
            raise DeviceError(f"[{self.section}] {self._where()}: smbus2 is not installed "
                              f"({exc})") from None

    def _start_chip(self) -> None:
        s: Pca9685Settings = self.settings
        with self._lock:
            bus = self._bus = open_i2c(s.bus, s.timeout_s)
            mode = bus.read_byte_data(s.address, chip.MODE1)
            asleep = (mode & ~chip.RESTART) | chip.SLEEP
            bus.write_byte_data(s.address, chip.MODE1, asleep)
            bus.write_byte_data(s.address, chip.PRESCALE, self.prescale)
            awake = (asleep & ~chip.SLEEP) | chip.AI
            bus.write_byte_data(s.address, chip.MODE1, awake)
            time.sleep(WAKE_S)
            bus.write_byte_data(s.address, chip.MODE1, awake | chip.RESTART)

    async def _probe(self) -> None:
        """Read MODE1 only: opening would sleep the chip, pausing every channel's pulses."""
        try:
            await asyncio.to_thread(self._read_mode)
        except OSError as exc:
            raise self._fail(exc) from None
        except ImportError as exc:
            raise DeviceError(f"[{self.section}] {self._where()}: smbus2 is not installed "
                              f"({exc})") from None
        finally:
            await asyncio.to_thread(self._drop)

    def _read_mode(self) -> None:
        s: Pca9685Settings = self.settings
        with self._lock:
            self._bus = open_i2c(s.bus, s.timeout_s)
            self._bus.read_byte_data(s.address, chip.MODE1)

    async def _send_pulses(self, pulses: dict[int, float]) -> None:
        try:
            await asyncio.to_thread(self._write_channels, pulses)
        except OSError as exc:
            raise self._fail(exc) from None

    def _write_channels(self, pulses: dict[int, float]) -> None:
        s: Pca9685Settings = self.settings
        with self._lock:
            if self._bus is None:
                raise OSError(errno.EIO, "bus closed")
            for channel, pulse in pulses.items():
                off = chip.counts_for(pulse, self.frequency_hz) if pulse > 0 else chip.FULL << 8
                self._bus.write_i2c_block_data(s.address, chip.led_register(channel),
                                               chip.led_bytes(0, off))

    async def _close(self) -> None:
        await asyncio.to_thread(self._drop)

    def _drop(self) -> None:
        with self._lock:
            bus, self._bus = self._bus, None
        if bus is not None:
            bus.close()

    def _health(self) -> dict[str, Any]:
        return {**super()._health(), "frequency_hz": round(self.frequency_hz, 3),
                "prescale": self.prescale}
