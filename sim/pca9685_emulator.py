# A PCA9685 PWM board on an emulated I²C bus: its register file, PRESCALE rules and pulse widths.
from __future__ import annotations

from drivers import pca9685_protocol as chip
from sim.i2c_bus import I2cDeviceEmulator


class Pca9685Chip:
    """The chip's registers as the datasheet has them. Writes to PRESCALE are taken only
    while MODE1's SLEEP bit is set (else ignored and counted in ``prescale_refused``); block
    transfers step through the registers only with MODE1's AI bit (else every byte goes to the
    first); writing RESTART = 1 clears it. While asleep the oscillator is off: no pulses."""

    def __init__(self) -> None:
        self.registers = bytearray(256)
        self.registers[chip.MODE1] = chip.MODE1_RESET
        self.registers[chip.PRESCALE] = chip.PRESCALE_RESET
        for channel in range(chip.CHANNELS):
            self.registers[chip.led_register(channel) + 3] = chip.FULL  # OFF_H: full off
        self.prescale_refused = 0
        self.writes = 0

    @property
    def asleep(self) -> bool:
        return bool(self.registers[chip.MODE1] & chip.SLEEP)

    @property
    def frequency_hz(self) -> float:
        return chip.frequency_of(self.registers[chip.PRESCALE])

    def write(self, register: int, data: tuple[int, ...]) -> None:
        auto = bool(self.registers[chip.MODE1] & chip.AI)
        for i, value in enumerate(data):
            self._write_one((register + i) % 256 if auto else register, value)

    def _write_one(self, register: int, value: int) -> None:
        self.writes += 1
        if register == chip.PRESCALE and not self.asleep:
            self.prescale_refused += 1
            return
        if register == chip.MODE1 and value & chip.RESTART:
            value &= ~chip.RESTART
        self.registers[register] = value

    def read(self, register: int, count: int) -> list[int]:
        auto = bool(self.registers[chip.MODE1] & chip.AI)
        return [self.registers[(register + i) % 256 if auto else register] for i in range(count)]

    def pulse_us(self, channel: int) -> float:
        """The pulse width the channel's pin carries, µs (0: off, or the chip asleep)."""
        if self.asleep:
            return 0.0
        base = chip.led_register(channel)
        on, off = chip.led_counts(list(self.registers[base:base + 4]))
        return chip.pulse_of(on, off, self.frequency_hz)


class Pca9685Emulator(I2cDeviceEmulator):
    """An I²C bus on a loopback TCP port (``drivers/i2c_wire.py`` lines) with one PCA9685 at
    ``address``; ``answering = False`` plays a board that does not acknowledge (unpowered,
    miswired): every transfer fails with EREMOTEIO, as the kernel's i2c-dev reports it."""

    def __init__(self, address: int = chip.DEFAULT_ADDRESS, *, host: str = "127.0.0.1",
                 port: int = 0) -> None:
        super().__init__(address, host=host, port=port)
        self.chip = Pca9685Chip()

    def servo_pulse_us(self, channel: int) -> float:
        """The pulse width a channel carries now, µs (0 = off)."""
        with self._lock:
            return self.chip.pulse_us(channel)

    def write(self, register: int, data: tuple[int, ...]) -> None:
        self.chip.write(register, data)

    def read(self, register: int, count: int) -> list[int]:
        return self.chip.read(register, count)
