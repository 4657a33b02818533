# The text lines an emulated I²C bus speaks (the simulator's stand-in for /dev/i2c-N). Pure.
from __future__ import annotations

import errno
import os
from dataclasses import dataclass

#: the prefix of a ``bus`` option naming an emulated bus: ``emulated:HOST:PORT``
EMULATED_PREFIX = "emulated:"
#: what a bus answers when no device acknowledges the address (as the kernel's i2c-dev does)
NO_DEVICE = errno.EREMOTEIO
OPS = ("wb", "rb", "wk", "rk")


@dataclass(frozen=True)
class I2cRequest:
    """One transfer: ``wb`` write a byte, ``rb`` read a byte, ``wk`` write a block, ``rk``
    read ``count`` bytes; to the device at ``address``, starting at register ``register``."""

    op: str
    address: int
    register: int
    data: tuple[int, ...] = ()
    count: int = 0

    def line(self) -> bytes:
        tail = self.data if self.op in ("wb", "wk") else (self.count,) if self.op == "rk" else ()
        return " ".join(map(str, (self.op, self.address, self.register, *tail))).encode() + b"\n"


def parse_request(line: bytes) -> I2cRequest:
    """A request line; ``ValueError`` when it is not one."""
    words = line.decode("ascii").split()
    if len(words) < 3 or words[0] not in OPS:
        raise ValueError(f"not an I2C request: {line!r}")
    op, numbers = words[0], [int(w) for w in words[1:]]
    if any(not 0 <= n <= 255 for n in numbers):
        raise ValueError(f"byte out of range: {line!r}")
    address, register, rest = numbers[0], numbers[1], tuple(numbers[2:])
    if op == "rk":
        return I2cRequest(op, address, register, count=rest[0] if rest else 1)
    return I2cRequest(op, address, register, data=rest)


def reply_line(values: list[int] | None = None, error: int = 0) -> bytes:
    """``ok``, ``v b0 b1 ...`` or ``e ERRNO``."""
    if error:
        return f"e {error}\n".encode()
    if values is None:
        return b"ok\n"
    return ("v " + " ".join(map(str, values)) + "\n").encode()


def parse_reply(line: bytes) -> list[int]:
    """The bytes a reply carries; ``OSError`` with the bus's errno for ``e ERRNO``."""
    words = line.decode("ascii").split()
    if not words:
        raise OSError(errno.EIO, "the emulated I2C bus closed the connection")
    if words[0] == "e":
        code = int(words[1])
        raise OSError(code, os.strerror(code))  # as the kernel's i2c-dev reports it
    return [int(w) for w in words[1:]]
