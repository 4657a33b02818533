# ROSArduinoBridge wire protocol (pure, no I/O): commands, replies, units; driver and emulator.
from __future__ import annotations

import math

# firmware defaults (ROSArduinoBridge.ino, joshnewans fork)
BAUDRATE = 57600
PID_RATE_HZ = 30.0
AUTO_STOP_S = 2.0  # AUTO_STOP_INTERVAL: motors stop this long after the last motor command
MAX_PWM = 255
DEFAULT_GAINS = (20, 12, 0, 50)  # Kp, Kd, Ki, Ko

# command letters (commands.h)
ANALOG_READ = "a"
GET_BAUDRATE = "b"
PIN_MODE = "c"
DIGITAL_READ = "d"
READ_ENCODERS = "e"
MOTOR_SPEEDS = "m"  # ticks per PID frame, closed loop
MOTOR_RAW_PWM = "o"  # raw PWM, open loop
PING = "p"
RESET_ENCODERS = "r"
UPDATE_PID = "u"
DIGITAL_WRITE = "w"
ANALOG_WRITE = "x"

OK = "OK"
INVALID_COMMAND = "Invalid Command"
COMMAND_END = b"\r"  # the firmware runs a command at CR
REPLY_END = b"\r\n"  # and answers with Serial.println
MAX_REPLY_LINE = 64  # longest sane reply ("-2147483648 -2147483648" is 23 bytes)


class ProtocolError(ValueError):
    """Bytes from the board that are not a ROSArduinoBridge reply."""


# -- host -> board ---------------------------------------------------------------------------

def encode_command(letter: str, *args: int | str) -> bytes:
    """A command line as the firmware reads it: letter, space-separated args, CR."""
    return " ".join([letter, *map(str, args)]).encode("ascii") + COMMAND_END


def encode_pid(kp: int, kd: int, ki: int, ko: int) -> bytes:
    return encode_command(UPDATE_PID, f"{kp}:{kd}:{ki}:{ko}")


# -- board -> host ---------------------------------------------------------------------------

def encode_reply(text: str) -> bytes:
    """One reply line as the firmware prints it."""
    return text.encode("ascii") + REPLY_END


def format_counts(left: int, right: int) -> str:
    """The reply to ``e``: both encoder counts."""
    return f"{left} {right}"


def decode_line(raw: bytes) -> str:
    """One reply line without its CRLF; anything but printable ASCII is a garbled reply."""
    text = raw.rstrip(b"\r")
    if not all(0x20 <= byte < 0x7F for byte in text):
        raise ProtocolError(f"garbled reply {raw!r}: non-printable byte")
    return text.decode("ascii")


def parse_ok(command: str, line: str) -> None:
    if line != OK:
        raise ProtocolError(f"reply to {command!r} was {line!r}, expected {OK!r}")


def parse_counts(line: str) -> tuple[int, int]:
    """The reply to ``e``: two signed encoder counts."""
    parts = line.split()
    if len(parts) != 2 or not all(_is_integer(part) for part in parts):
        raise ProtocolError(f"reply to 'e' was {line!r}, expected two integers")
    return int(parts[0]), int(parts[1])


def parse_baud(line: str) -> int:
    if not _is_integer(line.strip()):
        raise ProtocolError(f"reply to 'b' was {line!r}, expected the baud rate")
    return int(line)


def _is_integer(text: str) -> bool:
    return text.lstrip("+-").isdigit() and len(text) <= 11


class LineSplitter:
    """Bytes in, complete ``\\n``-terminated lines out; an endless line is a garbled stream."""

    def __init__(self, max_line: int = MAX_REPLY_LINE) -> None:
        self.max_line = max_line
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[bytes]:
        self._buffer += data
        *lines, rest = self._buffer.split(b"\n")
        self._buffer = bytearray(rest)
        if len(self._buffer) > self.max_line:
            raise ProtocolError(f"garbled reply: {len(self._buffer)} bytes without a line end")
        return [bytes(line) for line in lines]


# -- units -----------------------------------------------------------------------------------

def wrap_long(value: int) -> int:
    """Wrap to the firmware's signed 32-bit ``long`` (its encoder counters)."""
    return (value + 2**31) % 2**32 - 2**31


def count_delta(new: int, old: int) -> int:
    """Counts moved between two readings of a signed 32-bit counter, across wrap-around."""
    return wrap_long(new - old)


def rad_s_to_ticks(rad_s: float, counts_per_rev: int, pid_rate: float) -> int:
    """Wheel speed as encoder ticks per PID frame, the unit of ``m L R``."""
    return round(rad_s * counts_per_rev / (2 * math.pi) / pid_rate)


def ticks_to_rad_s(ticks_per_frame: int, counts_per_rev: int, pid_rate: float) -> float:
    """The wheel speed ``m L R`` asks for: ``ticks_per_frame`` encoder ticks every PID frame."""
    return ticks_per_frame * pid_rate * 2 * math.pi / counts_per_rev


def rad_s_to_pwm(rad_s: float, full_speed: float, max_pwm: int) -> int:
    """Wheel speed as a raw PWM value for ``o L R`` (linear, clamped to ``±max_pwm``)."""
    pwm = round(rad_s / full_speed * max_pwm) if full_speed > 0 else 0
    return max(-max_pwm, min(max_pwm, pwm))
