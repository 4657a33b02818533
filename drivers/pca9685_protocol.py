# The PCA9685 PWM chip: registers and arithmetic (pure; the device and its emulator share it).
from __future__ import annotations

#: the chip's default I²C address (A0..A5 low)
DEFAULT_ADDRESS = 0x40
#: the internal oscillator, Hz
OSCILLATOR_HZ = 25_000_000
#: counts per PWM period
COUNTS = 4096
CHANNELS = 16

MODE1 = 0x00
MODE2 = 0x01
LED0_ON_L = 0x06
ALL_LED_ON_L = 0xFA
PRESCALE = 0xFE

#: MODE1 bits
RESTART = 0x80
AI = 0x20  # register auto-increment
SLEEP = 0x10
ALLCALL = 0x01
#: bit 4 of LEDn_ON_H / LEDn_OFF_H: the output fully on / fully off
FULL = 0x10

#: MODE1 after power-up: asleep, answering the all-call address
MODE1_RESET = SLEEP | ALLCALL
#: the PRESCALE register after power-up (200 Hz)
PRESCALE_RESET = 0x1E
PRESCALE_MIN, PRESCALE_MAX = 3, 255


def prescale_for(frequency_hz: float, oscillator_hz: float = OSCILLATOR_HZ) -> int:
    """PRESCALE = round(osc / (4096 * f)) - 1 (datasheet 7.3.5); 121 for 50 Hz."""
    value = round(oscillator_hz / (COUNTS * frequency_hz)) - 1
    if not PRESCALE_MIN <= value <= PRESCALE_MAX:
        raise ValueError(f"{frequency_hz} Hz is outside the PCA9685's range")
    return value


def frequency_of(prescale: int, oscillator_hz: float = OSCILLATOR_HZ) -> float:
    """The PWM frequency a PRESCALE value gives, Hz."""
    return oscillator_hz / (COUNTS * (prescale + 1))


def led_register(channel: int) -> int:
    """LEDn_ON_L of a channel; ON_H, OFF_L, OFF_H follow it."""
    if not 0 <= channel < CHANNELS:
        raise ValueError(f"channel {channel} is not 0..{CHANNELS - 1}")
    return LED0_ON_L + 4 * channel


def counts_for(pulse_us: float, frequency_hz: float) -> int:
    """The OFF count (ON = 0) of a pulse of ``pulse_us`` at the frequency the chip runs."""
    return min(COUNTS - 1, max(0, round(pulse_us * 1e-6 * frequency_hz * COUNTS)))


def pulse_of(on: int, off: int, frequency_hz: float) -> float:
    """The pulse width (µs) of an output's ON and OFF counts (0 when fully off)."""
    if off & (FULL << 8) or (on == off and not on & (FULL << 8)):
        return 0.0
    if on & (FULL << 8):
        return 1e6 / frequency_hz
    return ((off - on) % COUNTS) * 1e6 / (frequency_hz * COUNTS)


def step_us(frequency_hz: float) -> float:
    """One count of the PWM period, µs (the chip's pulse resolution)."""
    return 1e6 / (frequency_hz * COUNTS)


def led_bytes(on: int, off: int) -> list[int]:
    """ON_L, ON_H, OFF_L, OFF_H of an output."""
    return [on & 0xFF, on >> 8, off & 0xFF, off >> 8]


def led_counts(data: list[int]) -> tuple[int, int]:
    """ON and OFF (13 bits: the FULL bit included) from the four LED register bytes."""
    return data[0] | (data[1] & 0x1F) << 8, data[2] | (data[3] & 0x1F) << 8
