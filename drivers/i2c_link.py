# An I²C bus with smbus2's methods: /dev/i2c-N through smbus2, or the simulator's emulated bus.
from __future__ import annotations

import socket
from typing import Any, Protocol

from drivers.i2c_wire import EMULATED_PREFIX, I2cRequest, parse_reply


class I2cBus(Protocol):
    """The part of ``smbus2.SMBus`` the devices use."""

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None: ...

    def read_byte_data(self, i2c_addr: int, register: int) -> int: ...

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: list[int]) -> None: ...

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]: ...

    def close(self) -> None: ...


class EmulatedBus:
    """smbus2's methods over the simulator's line protocol (``drivers/i2c_wire.py``): one
    request, one reply, each wait bounded by ``timeout_s``."""

    def __init__(self, host: str, port: int, timeout_s: float) -> None:
        self._sock = socket.create_connection((host, port), timeout=timeout_s)
        self._file = self._sock.makefile("rb")

    def _call(self, request: I2cRequest) -> list[int]:
        self._sock.sendall(request.line())
        return parse_reply(self._file.readline())

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None:
        self._call(I2cRequest("wb", i2c_addr, register, (value,)))

    def read_byte_data(self, i2c_addr: int, register: int) -> int:
        return self._call(I2cRequest("rb", i2c_addr, register))[0]

    def write_i2c_block_data(self, i2c_addr: int, register: int, data: list[int]) -> None:
        self._call(I2cRequest("wk", i2c_addr, register, tuple(data)))

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        return self._call(I2cRequest("rk", i2c_addr, register, count=length))

    def close(self) -> None:
        self._file.close()
        self._sock.close()


def bus_number(bus: str) -> int | None:
    """The N of ``/dev/i2c-N`` or ``N``; None for anything else."""
    tail = bus.removeprefix("/dev/i2c-")
    return int(tail) if tail.isdigit() else None


def check_bus(bus: str) -> str | None:
    """Why ``bus`` names no bus, or None."""
    if bus_number(bus) is not None:
        return None
    if bus.startswith(EMULATED_PREFIX):
        _, _, port = bus.removeprefix(EMULATED_PREFIX).rpartition(":")
        if port.isdigit():
            return None
    return (f"expected /dev/i2c-N, N or {EMULATED_PREFIX}HOST:PORT (the simulator's), "
            f"got {bus!r}")


def open_i2c(bus: str, timeout_s: float) -> I2cBus:
    """Open ``bus``: ``/dev/i2c-N`` (or ``N``) through smbus2, ``emulated:HOST:PORT`` through
    :class:`EmulatedBus`. ``OSError`` when it cannot be opened."""
    number = bus_number(bus)
    if number is not None:
        from smbus2 import SMBus

        smbus: Any = SMBus(number)
        return smbus
    host, _, port = bus.removeprefix(EMULATED_PREFIX).rpartition(":")
    return EmulatedBus(host, int(port), timeout_s)
