# A PCA9685 PWM board on an emulated I²C bus: its register file, PRESCALE rules and pulse widths.
from __future__ import annotations

import contextlib
import socket
import threading
from typing import Any

from drivers import pca9685_protocol as chip
from drivers.i2c_wire import EMULATED_PREFIX, NO_DEVICE, I2cRequest, parse_request, reply_line


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


class Pca9685Emulator:
    """An I²C bus on a loopback TCP port (``drivers/i2c_wire.py`` lines) with one PCA9685 at
    ``address``; ``answering = False`` plays a board that does not acknowledge (unpowered,
    miswired): every transfer fails with EREMOTEIO, as the kernel's i2c-dev reports it."""

    def __init__(self, address: int = chip.DEFAULT_ADDRESS, *, host: str = "127.0.0.1",
                 port: int = 0) -> None:
        self.address = address
        self.chip = Pca9685Chip()
        self.answering = True
        self.host, self.port = host, port
        self._lock = threading.Lock()
        self._listener: socket.socket | None = None
        self._threads: list[threading.Thread] = []
        self._conns: list[socket.socket] = []

    @property
    def bus(self) -> str:
        """The ``bus`` option that reaches this emulator."""
        return f"{EMULATED_PREFIX}{self.host}:{self.port}"

    def start(self) -> Pca9685Emulator:
        listener = socket.create_server((self.host, self.port))
        self.port = listener.getsockname()[1]
        self._listener = listener
        self._spawn(self._accept_loop)
        return self

    def close(self) -> None:
        listener, self._listener = self._listener, None
        if listener is not None:
            with contextlib.suppress(OSError):
                listener.shutdown(socket.SHUT_RDWR)
            listener.close()
        for conn in list(self._conns):
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
            conn.close()
        for thread in self._threads:
            thread.join(timeout=2.0)

    def servo_pulse_us(self, channel: int) -> float:
        """The pulse width a channel carries now, µs (0 = off)."""
        with self._lock:
            return self.chip.pulse_us(channel)

    def _spawn(self, target: Any, *args: Any) -> None:
        thread = threading.Thread(target=target, args=args, name="pca9685-emulator",
                                  daemon=True)
        self._threads.append(thread)
        thread.start()

    def _accept_loop(self) -> None:
        while (listener := self._listener) is not None:
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            self._conns.append(conn)
            self._spawn(self._serve, conn)

    def _serve(self, conn: socket.socket) -> None:
        with conn, conn.makefile("rb") as lines:
            for line in lines:
                try:
                    reply = self.transfer(parse_request(line))
                except ValueError:
                    reply = reply_line(error=22)
                try:
                    conn.sendall(reply)
                except OSError:
                    return

    def transfer(self, request: I2cRequest) -> bytes:
        """One transfer on the bus, answered as a reply line."""
        if request.address != self.address or not self.answering:
            return reply_line(error=NO_DEVICE)
        with self._lock:
            if request.op in ("wb", "wk"):
                self.chip.write(request.register, request.data)
                return reply_line()
            count = 1 if request.op == "rb" else request.count
            return reply_line(self.chip.read(request.register, count))
