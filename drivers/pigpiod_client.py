# Connecting the unmodified pigpio client to pigpiod, and dropping it, for drivers and devices.
from __future__ import annotations

import atexit
import contextlib
import socket
from typing import Any

from drivers.base import DriverFault


def probe_tcp(host: str, port: int, timeout: float) -> None:
    """Fail fast with a clear message when nothing listens at host:port.

    The pigpio client connects without a timeout; probing first keeps an unreachable pigpiod
    from blocking a reconnect attempt for minutes.
    """
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as exc:
        raise DriverFault(f"pigpiod unreachable at {host}:{port}: {exc}") from None


def connect_pigpio(host: str, port: int, timeout: float) -> Any:
    """Connect the unmodified pigpio client; raise DriverFault when pigpiod is not there."""
    import pigpio

    probe_tcp(host, port, timeout)
    pi = pigpio.pi(host, port, show_errors=False)
    if not pi.connected:
        raise DriverFault(f"pigpiod unreachable at {host}:{port}")
    pi.sl.s.settimeout(timeout)  # command replies: a hung pigpiod becomes an error, not a hang
    return pi


def drop_pigpio(pi: Any, *, peer_alive: bool) -> None:
    """Release a pigpio connection; with a dead or hung peer, without waiting for it.

    With a live peer, ``pi.stop()`` sends NC and the client's notification thread ends on the
    reply. Otherwise that thread would spin on (or block in) a dead socket, so it is told to
    stop and its socket is shut down.
    """
    notify = getattr(pi, "_notify", None)
    if peer_alive:
        with contextlib.suppress(Exception):
            pi.stop()
    if notify is not None and notify.go:
        notify.go = False
        with contextlib.suppress(OSError):
            notify.sl.s.shutdown(socket.SHUT_RDWR)
    sock = getattr(pi.sl, "s", None)
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.close()
        pi.sl.s = None
    pi._notify, pi.connected = None, False
    atexit.unregister(pi.stop)
