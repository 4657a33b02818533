# An emulated I²C bus on a loopback TCP port with one device on it: every I²C emulator's seam.
from __future__ import annotations

import contextlib
import errno
import socket
import threading
from abc import ABC, abstractmethod
from typing import Any, Self

from drivers.i2c_wire import EMULATED_PREFIX, NO_DEVICE, I2cRequest, parse_request, reply_line


class I2cDeviceEmulator(ABC):
    """A bus speaking ``drivers/i2c_wire.py`` lines with one device at ``address``; a subclass
    is the device's register file (:meth:`write`, :meth:`read`, called under ``_lock``).
    Faults it plays: ``answering = False`` a device that does not acknowledge (unpowered,
    miswired: EREMOTEIO, as the kernel's i2c-dev reports it); ``stuck = True`` a bus whose
    SDA is held low (every transfer times out: ETIMEDOUT)."""

    def __init__(self, address: int, *, host: str = "127.0.0.1", port: int = 0) -> None:
        self.address = address
        self.answering = True
        self.stuck = False
        self.host, self.port = host, port
        self._lock = threading.Lock()
        self._listener: socket.socket | None = None
        self._threads: list[threading.Thread] = []
        self._conns: list[socket.socket] = []

    @property
    def bus(self) -> str:
        """The ``bus`` option that reaches this emulator."""
        return f"{EMULATED_PREFIX}{self.host}:{self.port}"

    def start(self) -> Self:
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

    @abstractmethod
    def write(self, register: int, data: tuple[int, ...]) -> None: ...

    @abstractmethod
    def read(self, register: int, count: int) -> list[int]: ...

    def _spawn(self, target: Any, *args: Any) -> None:
        thread = threading.Thread(target=target, args=args,
                                  name=f"{type(self).__name__}", daemon=True)
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
                    reply = reply_line(error=errno.EINVAL)
                try:
                    conn.sendall(reply)
                except OSError:
                    return

    def transfer(self, request: I2cRequest) -> bytes:
        """One transfer on the bus, answered as a reply line."""
        if self.stuck:
            return reply_line(error=errno.ETIMEDOUT)
        if request.address != self.address or not self.answering:
            return reply_line(error=NO_DEVICE)
        with self._lock:
            if request.op in ("wb", "wk"):
                self.write(request.register, request.data)
                return reply_line()
            count = 1 if request.op == "rb" else request.count
            return reply_line(self.read(request.register, count))
