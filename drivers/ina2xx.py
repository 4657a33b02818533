# A battery's voltage and current through an INA219 or INA226 current monitor over I²C (smbus2).
from __future__ import annotations

import asyncio
import errno
import threading
from dataclasses import dataclass
from typing import Any, ClassVar

from base.options import option, shared_option
from drivers import ina2xx_protocol as ina
from drivers.devices import DeviceError, Sensor
from drivers.i2c_link import I2cBus, check_bus, open_i2c

#: below this the bus input sees no battery (a loose Vin-/VBUS wire), V
NO_BATTERY_V = 1.0
#: the current register may differ from shunt / R by this much (rounding, conversion timing)
#: before the calibration is taken as lost (a chip reset by a brown-out reads 0), A
CAL_TOLERANCE_FRACTION = 0.05

#: the keys of an INA2xx, declared once (the [battery] section has them too)
INA_BUS = shared_option("/dev/i2c-1", "the I2C bus: /dev/i2c-N (or N); the simulator writes "
                        "emulated:HOST:PORT", check=check_bus)
INA_ADDRESS = shared_option(ina.DEFAULT_ADDRESS, "the chip's I2C address (64 = 0x40 with A0, "
                            "A1 to GND)", minval=0x03, maxval=0x77)
INA_SHUNT_OHMS = shared_option(0.1, "the shunt resistor, ohm (INA219 breakouts: 0.1; INA226: "
                               "0.1 or 0.002)", above=0.0, maxval=100.0)
INA_MAX_CURRENT_A = shared_option(0.0, "the largest current expected through the shunt, A "
                                  "(sets the calibration and the gain); 0 = what the shunt "
                                  "carries at the chip's full scale (0.1 ohm: INA219 3.2 A, "
                                  "INA226 0.82 A)", minval=0.0, maxval=1000.0)


@dataclass(frozen=True)
class InaSettings:
    """An ina219 / ina226 device's keys."""

    bus: str = option(**INA_BUS)
    address: int = option(**INA_ADDRESS)
    shunt_ohms: float = option(**INA_SHUNT_OHMS)
    max_current_a: float = option(**INA_MAX_CURRENT_A)
    timeout_s: float = option(1.0, "each transfer on an emulated bus, s", above=0.0, maxval=30.0)


class InaMonitor(Sensor):
    """A battery monitor on an INA2xx. ``open`` resets the chip, checks it is the chip it should
    be, writes the configuration and the calibration and reads them back; ``read`` gives
    ``voltage`` (V at the bus input), ``current`` (A through the shunt, positive into the
    load), ``power`` (W) and ``shunt_mv``. A read that cannot be trusted (no battery on the bus
    input, a shunt beyond its range, a chip that lost its calibration twice) is a
    :class:`DeviceError` saying what to check, never a number."""

    SETTINGS = InaSettings
    CHIP: ClassVar[ina.Chip]

    def __init__(self, options: Any, *, section: str) -> None:
        super().__init__(options, section=section)
        s: InaSettings = self.settings
        try:
            most = s.max_current_a or self.CHIP.shunt_full_scale_v / s.shunt_ohms
            self.calibration = ina.calibrate(self.CHIP, s.shunt_ohms, most)
        except ValueError as exc:
            raise ValueError(f"[{section}] shunt_ohms, max_current_a: {exc}") from None
        self._bus: I2cBus | None = None
        self._lock = threading.Lock()
        #: times the chip was found without its calibration (reset by a brown-out) and redone
        self.recalibrations = 0
        self.reads = 0

    def readings(self) -> tuple[str, ...]:
        return ("voltage", "current", "power", "shunt_mv")

    def where(self) -> str:
        s: InaSettings = self.settings
        return f"{self.CHIP.name} at 0x{s.address:02x} on {s.bus}"

    def _fail(self, exc: OSError) -> DeviceError:
        where = f"[{self.section}] {self.where()}"
        if exc.errno in (errno.EREMOTEIO, errno.ENXIO):
            return DeviceError(f"{where}: no answer ({exc.strerror or exc}): check its wiring "
                               "(SDA, SCL, VCC, GND) and its address")
        if exc.errno in (errno.ETIMEDOUT, errno.EAGAIN) or isinstance(exc, TimeoutError):
            return DeviceError(f"{where}: the bus is stuck (timed out; a device holding SDA "
                               "low?): check the wiring, power-cycle the I2C devices")
        if exc.errno == errno.ENOENT:
            return DeviceError(f"{where}: no such bus: enable I2C (raspi-config: Interface "
                               "options, I2C) or fix the bus option")
        return DeviceError(f"{where}: {exc}")

    # -- register access (under the lock, in a worker thread) ------------------------------

    def _get(self, register: int) -> int:
        assert self._bus is not None
        s: InaSettings = self.settings
        return ina.bytes_word(self._bus.read_i2c_block_data(s.address, register, 2))

    def _set(self, register: int, word: int) -> None:
        assert self._bus is not None
        s: InaSettings = self.settings
        self._bus.write_i2c_block_data(s.address, register, ina.word_bytes(word))

    # -- lifecycle ---------------------------------------------------------------------------

    async def _open(self) -> None:
        await self._run(self._start_chip, drop=True)

    async def _run(self, work: Any, *, drop: bool = False) -> Any:
        try:
            return await asyncio.to_thread(work)
        except OSError as exc:
            if drop:
                await asyncio.to_thread(self._drop)
            raise self._fail(exc) from None
        except ImportError as exc:
            raise DeviceError(f"[{self.section}] {self.where()}: smbus2 is not installed "
                              f"({exc})") from None
        except DeviceError:
            if drop:
                await asyncio.to_thread(self._drop)
            raise

    def _start_chip(self) -> None:
        s: InaSettings = self.settings
        with self._lock:
            self._bus = open_i2c(s.bus, s.timeout_s)
            self._set(ina.CONFIG, ina.RESET)
            config = self._get(ina.CONFIG)
            self._identify(config)
            self._program()

    def _identify(self, config: int) -> None:
        """After a reset CONFIG holds its reset value (INA226: and the IDs are TI's)."""
        chip = self.CHIP
        if chip is ina.INA226:
            ids = self._get(ina.MANUFACTURER_ID), self._get(ina.DIE_ID)
            if ids != (ina.INA226_MANUFACTURER, ina.INA226_DIE):
                raise DeviceError(f"[{self.section}] {self.where()}: the chip there is not an "
                                  f"INA226 (IDs 0x{ids[0]:04x} 0x{ids[1]:04x}): check the "
                                  "address and the device option")
        if config != chip.config_reset:
            raise DeviceError(f"[{self.section}] {self.where()}: after a reset its "
                              f"configuration reads 0x{config:04x}, not the {chip.name}'s "
                              f"0x{chip.config_reset:04x}: another chip answers there; check "
                              "the address and the device option")

    def _program(self) -> None:
        cal = self.calibration
        self._set(ina.CONFIG, cal.config)
        self._set(ina.CALIBRATION, cal.cal)
        back = self._get(ina.CONFIG), self._get(ina.CALIBRATION)
        if back != (cal.config, cal.cal):
            raise DeviceError(f"[{self.section}] {self.where()}: wrote configuration "
                              f"0x{cal.config:04x} and calibration {cal.cal}, read back "
                              f"0x{back[0]:04x} and {back[1]}: a bad connection (SDA)?")

    async def _close(self) -> None:
        await asyncio.to_thread(self._drop)

    def _drop(self) -> None:
        with self._lock:
            bus, self._bus = self._bus, None
        if bus is not None:
            bus.close()

    # -- reading -----------------------------------------------------------------------------

    async def _read(self) -> dict[str, float]:
        try:
            values: dict[str, float] = await self._run(self._measure)
        except DeviceError as exc:
            self.fault = str(exc)
            raise
        self.fault = None
        self.reads += 1
        return values

    def _measure(self) -> dict[str, float]:
        with self._lock:
            if self._bus is None:
                raise OSError(errno.EIO, "bus closed")
            values = self._sample()
            if values is None:  # the calibration was lost: program the chip again, once
                self.recalibrations += 1
                self._program()
                values = self._sample()
            if values is None:
                raise DeviceError(f"[{self.section}] {self.where()}: its current register "
                                  "disagrees with its shunt voltage after a recalibration: "
                                  "check the chip's supply (VCC) and shunt_ohms")
        return values

    def _sample(self) -> dict[str, float] | None:
        """One reading, or None when the chip's calibration is gone (it was reset)."""
        chip, cal = self.CHIP, self.calibration
        shunt_count = ina.to_signed(self._get(ina.SHUNT_VOLTAGE))
        bus = self._get(ina.BUS_VOLTAGE)
        current_count = ina.to_signed(self._get(ina.CURRENT))
        overflow = bus & ina.INA219_OVF if chip is ina.INA219 \
            else self._get(ina.MASK_ENABLE) & ina.INA226_OVF
        shunt_v = shunt_count * chip.shunt_lsb_v
        full = ina.ina219_shunt_full_scale(cal.config) if chip is ina.INA219 \
            else chip.shunt_full_scale_v
        if overflow or abs(shunt_v) >= full * 0.999:
            raise DeviceError(f"[{self.section}] {self.where()}: the shunt's "
                              f"{shunt_v * 1e3:.1f} mV is at the end of its range: the "
                              "current is beyond max_current_a, or shunt_ohms is wrong")
        volts = ina.bus_voltage(chip, bus)
        if volts < NO_BATTERY_V:
            raise DeviceError(f"[{self.section}] {self.where()}: the bus input reads "
                              f"{volts:.2f} V: no battery on VIN-/VBUS; check that wire")
        by_shunt = shunt_v / cal.shunt_ohms
        current = current_count * cal.current_lsb_a
        slack = max(abs(by_shunt) * CAL_TOLERANCE_FRACTION, 4 * cal.current_lsb_a)
        if abs(current - by_shunt) > slack:
            return None
        return {"voltage": volts, "current": current, "power": volts * current,
                "shunt_mv": shunt_v * 1e3}

    def _health(self) -> dict[str, Any]:
        cal = self.calibration
        return {"chip": self.CHIP.name, "calibration": cal.cal,
                "current_lsb_ma": round(cal.current_lsb_a * 1e3, 4),
                "recalibrations": self.recalibrations, "reads": self.reads}


class Ina219Monitor(InaMonitor):
    CHIP = ina.INA219


class Ina226Monitor(InaMonitor):
    CHIP = ina.INA226
