# An INA219 or INA226 current monitor on an emulated I²C bus, measuring a simulated battery.
from __future__ import annotations

from collections.abc import Callable

from drivers import ina2xx_protocol as ina
from sim.battery import BatteryModel
from sim.i2c_bus import I2cDeviceEmulator

#: what the chip measures now: (bus voltage V, current A through the shunt into the load)
Source = Callable[[], tuple[float, float]]


class InaChip:
    """The chip's register file as its datasheet has it: 16-bit registers sent most
    significant byte first; a write of CONFIG's RST bit resets every register; the shunt,
    bus, current and power registers convert what :attr:`source` gives through the board's
    real ``shunt_ohms``; CURRENT and POWER are 0 while CALIBRATION is 0 (after a reset)."""

    def __init__(self, chip: ina.Chip, source: Source, shunt_ohms: float = 0.1) -> None:
        self.chip = chip
        self.source = source
        self.shunt_ohms = shunt_ohms
        #: a loose wire between the battery and VIN-/VBUS: the bus input reads 0 V
        self.bus_disconnected = False
        self.config = chip.config_reset
        self.calibration = 0
        self.mask_enable = 0
        self._pointer = 0

    def reset(self) -> None:
        """Power-up values (as after a brown-out)."""
        self.config, self.calibration, self.mask_enable = self.chip.config_reset, 0, 0

    def write(self, register: int, data: tuple[int, ...]) -> None:
        self._pointer = register
        if len(data) < 2:
            return  # a pointer write (or a half word the chip ignores)
        word = ina.bytes_word(list(data[:2]))
        if register == ina.CONFIG:
            if word & ina.RESET:
                self.reset()
            else:
                self.config = word | (0x4000 if self.chip is ina.INA226 else 0)
        elif register == ina.CALIBRATION:
            self.calibration = word & 0xFFFE
        elif register == ina.MASK_ENABLE and self.chip is ina.INA226:
            self.mask_enable = word & 0xFC03

    def read(self, register: int, count: int) -> list[int]:
        data = ina.word_bytes(self.register(register))
        return (data * ((count + 1) // 2))[:count]

    def _full_scale(self) -> float:
        if self.chip is ina.INA219:
            return ina.ina219_shunt_full_scale(self.config)
        return self.chip.shunt_full_scale_v

    def register(self, register: int) -> int:
        chip = self.chip
        volts, amps = self.source()
        if self.bus_disconnected:
            volts = 0.0
        shunt, overflow = ina.shunt_count(chip, amps * self.shunt_ohms, self._full_scale())
        current = int(shunt * self.calibration / chip.current_divisor)
        bus_count = ina.bus_word(chip, volts) >> (3 if chip is ina.INA219 else 0)
        power = abs(current) * bus_count // (5000 if chip is ina.INA219 else 20000)
        if register == ina.CONFIG:
            return self.config
        if register == ina.SHUNT_VOLTAGE:
            return ina.to_word(shunt)
        if register == ina.BUS_VOLTAGE:
            flags = ina.INA219_CNVR | (ina.INA219_OVF if overflow else 0)
            return ina.bus_word(chip, volts, flags if chip is ina.INA219 else 0)
        if register == ina.POWER:
            return min(power, 0xFFFF)
        if register == ina.CURRENT:
            return ina.to_word(current)
        if register == ina.CALIBRATION:
            return self.calibration
        if chip is ina.INA226:
            if register == ina.MASK_ENABLE:
                return self.mask_enable | ina.INA226_CVRF | (ina.INA226_OVF if overflow else 0)
            if register == ina.MANUFACTURER_ID:
                return ina.INA226_MANUFACTURER
            if register == ina.DIE_ID:
                return ina.INA226_DIE
        return 0


class InaEmulator(I2cDeviceEmulator):
    """An INA219/INA226 breakout on an emulated I²C bus at ``address``: it measures
    :attr:`battery` (a :class:`BatteryModel`, the simulator's pack) through a shunt of
    ``shunt_ohms``. Faults: ``answering``, ``stuck`` (the bus), ``chip.bus_disconnected``,
    ``chip.reset()`` (a brown-out)."""

    def __init__(self, kind: str, address: int = ina.DEFAULT_ADDRESS, *,
                 battery: BatteryModel | None = None, shunt_ohms: float = 0.1,
                 host: str = "127.0.0.1", port: int = 0) -> None:
        super().__init__(address, host=host, port=port)
        self.battery = battery or BatteryModel()
        self.chip = InaChip(ina.CHIPS[kind], lambda: self.battery.measure(), shunt_ohms)

    def use_battery(self, battery: BatteryModel) -> None:
        """Measure the simulated world's pack (``run --sim``)."""
        with self._lock:
            self.battery = battery

    def write(self, register: int, data: tuple[int, ...]) -> None:
        self.chip.write(register, data)

    def read(self, register: int, count: int) -> list[int]:
        return self.chip.read(register, count)
