# The INA219 and INA226 current monitors: registers, calibration and arithmetic (pure; shared by
# the driver and its emulator).
from __future__ import annotations

import math
from dataclasses import dataclass

#: both chips' default I²C address (A0, A1 to GND)
DEFAULT_ADDRESS = 0x40

CONFIG = 0x00
SHUNT_VOLTAGE = 0x01
BUS_VOLTAGE = 0x02
POWER = 0x03
CURRENT = 0x04
CALIBRATION = 0x05
#: INA226 only
MASK_ENABLE = 0x06
MANUFACTURER_ID = 0xFE
DIE_ID = 0xFF

RESET = 0x8000
#: MODE bits: shunt and bus, continuous
MODE_CONTINUOUS = 0x7

#: INA219 bus voltage register flags: conversion ready, math overflow
INA219_CNVR = 0x2
INA219_OVF = 0x1
#: INA226 mask/enable flags: conversion ready, math overflow
INA226_CVRF = 0x8
INA226_OVF = 0x4
#: Texas Instruments' ID and the INA226's die ID
INA226_MANUFACTURER = 0x5449
INA226_DIE = 0x2260


@dataclass(frozen=True)
class Chip:
    """What differs between the two chips (datasheets SBOS448G §8.6, SBOS547A §7.6)."""

    name: str
    #: CONFIG after power-up or a reset
    config_reset: int
    #: shunt voltage register LSB, V
    shunt_lsb_v: float
    #: bus voltage LSB, V (INA219: of the register shifted right by 3)
    bus_lsb_v: float
    #: the calibration formula's constant: CAL = trunc(k / (current_lsb * shunt_ohms))
    cal_constant: float
    #: CURRENT = SHUNT * CAL / divisor
    current_divisor: int
    #: POWER LSB = power_factor * current LSB
    power_factor: int
    #: the largest shunt voltage the chip measures, V
    shunt_full_scale_v: float


INA219 = Chip("INA219", 0x399F, 10e-6, 4e-3, 0.04096, 4096, 20, 0.32)
INA226 = Chip("INA226", 0x4127, 2.5e-6, 1.25e-3, 0.00512, 2048, 25, 0.08192)
CHIPS = {"ina219": INA219, "ina226": INA226}

#: INA219 PGA ranges (shunt full scale, V) => PG bits (config bits 12..11)
INA219_GAINS = ((0.04, 0), (0.08, 1), (0.16, 2), (0.32, 3))


@dataclass(frozen=True)
class Calibration:
    """How one chip is programmed for a shunt and a largest expected current."""

    chip: Chip
    shunt_ohms: float
    current_lsb_a: float
    cal: int
    config: int

    @property
    def power_lsb_w(self) -> float:
        return self.chip.power_factor * self.current_lsb_a


def calibrate(chip: Chip, shunt_ohms: float, max_current_a: float) -> Calibration:
    """The calibration register and configuration for a shunt of ``shunt_ohms`` and currents up
    to ``max_current_a``; ``ValueError`` when the shunt's voltage at that current is beyond the
    chip's range or the calibration does not fit its 15 bits."""
    if not (shunt_ohms > 0 and max_current_a > 0 and math.isfinite(shunt_ohms * max_current_a)):
        raise ValueError("shunt_ohms and max_current_a must be positive")
    drop = shunt_ohms * max_current_a
    if drop > chip.shunt_full_scale_v * (1 + 1e-9):
        raise ValueError(f"{max_current_a:g} A through {shunt_ohms:g} ohm drops "
                         f"{drop * 1e3:.1f} mV, beyond the {chip.name}'s "
                         f"{chip.shunt_full_scale_v * 1e3:g} mV: a smaller shunt or max_current_a")
    current_lsb = max_current_a / 32768
    cal = int(chip.cal_constant / (current_lsb * shunt_ohms))
    if cal > 0xFFFE:
        raise ValueError(f"calibration {cal} does not fit the {chip.name}'s register: raise "
                         "max_current_a or shunt_ohms")
    cal &= 0xFFFE  # bit 0 is read-only (0) on both chips
    current_lsb = chip.cal_constant / (cal * shunt_ohms)  # the LSB the whole number gives
    return Calibration(chip, shunt_ohms, current_lsb, cal, config_for(chip, drop))


def config_for(chip: Chip, max_shunt_v: float) -> int:
    """The configuration: continuous shunt and bus conversions; INA219: 32 V bus range, 12-bit
    samples averaged 8 times, the smallest gain that holds ``max_shunt_v``; INA226: 16
    samples of 1.1 ms each."""
    if chip is INA219:
        gain = next(bits for full, bits in INA219_GAINS if max_shunt_v <= full * (1 + 1e-9))
        adc = 0b1011  # 8 samples of 12 bits, 4.26 ms
        return 0x2000 | gain << 11 | adc << 7 | adc << 3 | MODE_CONTINUOUS
    return 0x4000 | 0b010 << 9 | 0b100 << 6 | 0b100 << 3 | MODE_CONTINUOUS


def ina219_shunt_full_scale(config: int) -> float:
    """The INA219's shunt range (V) its configuration's PG bits select."""
    bits = (config >> 11) & 0x3
    return next(full for full, b in INA219_GAINS if b == bits)


def to_signed(word: int) -> int:
    return word - 0x10000 if word & 0x8000 else word


def to_word(value: int) -> int:
    return value & 0xFFFF


def word_bytes(word: int) -> list[int]:
    """A register's two bytes as the chips send them: most significant first."""
    return [(word >> 8) & 0xFF, word & 0xFF]


def bytes_word(data: list[int]) -> int:
    return (data[0] << 8) | data[1]


def bus_voltage(chip: Chip, word: int) -> float:
    """The bus voltage (V) of the BUS_VOLTAGE register (INA219: bits 15..3)."""
    return (word >> 3 if chip is INA219 else word) * chip.bus_lsb_v


def bus_word(chip: Chip, volts: float, flags: int = 0) -> int:
    """The BUS_VOLTAGE register for ``volts`` (INA219: with its CNVR/OVF ``flags``)."""
    if chip is INA219:
        count = min(max(round(volts / chip.bus_lsb_v), 0), 0x1FFF)
        return count << 3 | flags
    return min(max(round(volts / chip.bus_lsb_v), 0), 0x7FFF)


def shunt_count(chip: Chip, volts: float, full_scale_v: float) -> tuple[int, bool]:
    """The signed SHUNT_VOLTAGE count for ``volts`` and whether it saturated the range."""
    limit = round(full_scale_v / chip.shunt_lsb_v)
    count = round(volts / chip.shunt_lsb_v)
    return max(-limit, min(limit, count)), abs(count) > limit
