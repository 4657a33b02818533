# Listening ports: what each component listens on, checked before anything starts, and a taken
# port explained (who holds it, how to pick others) instead of "[Errno 98] address in use".
from __future__ import annotations

import errno
import socket
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from aiohttp import web

from base.ports import listeners

#: `arbiterd run` exits with this when a port it must listen on is taken (sysexits EX_TEMPFAIL:
#: another instance, or a previous one still closing; systemd's Restart= tries again)
EXIT_PORT_IN_USE = 75
OTHER_PORTS = ("or run this one on other ports: arbiterd run --http-port PORT --ws-port PORT "
               "(or [http] port and [rosbridge] port in its config)")


@dataclass(frozen=True)
class Listener:
    """A TCP port a component listens on: ``[section] host`` and ``[section] port``."""

    section: str
    host: str
    port: int


class PortInUse(OSError):
    """Ports to listen on are taken; the text names who holds each and what to do."""

    def __init__(self, taken: Sequence[Listener]) -> None:
        super().__init__(errno.EADDRINUSE, in_use_message(taken))
        self.taken = list(taken)

    def __str__(self) -> str:
        return str(self.strerror)


def in_use_message(taken: Sequence[Listener]) -> str:
    """Who holds each taken port (another arbiterd, another program, or a process this user
    cannot see) and how to start anyway."""
    parts, holders = [], []
    for listener in taken:
        found = listeners(listener.port)
        holders.append(found[0] if found else None)
        who = found[0] if found else "a process of another user"
        parts.append(f"port {listener.port} ([{listener.section}] port) is in use by {who}")
    if any(holder is not None and holder.daemon for holder in holders):
        what = ("another arbiterd is running (`arbiterd status` shows it; the service stops "
                "with sudo systemctl stop robot.target)")
    elif None in holders:
        what = ("the arbiterd service runs as its own user (`arbiterd status` shows it; sudo "
                "systemctl stop robot.target stops it); another program: stop it")
    else:
        what = "stop it"
    return f"{'; '.join(parts)}: {what}, {OTHER_PORTS}"


def as_port_error(listener: Listener, exc: OSError) -> OSError:
    """``exc`` from binding ``listener``, as :class:`PortInUse` when the port is taken."""
    return PortInUse([listener]) if exc.errno == errno.EADDRINUSE else exc


async def start_listening(runner: web.AppRunner, listener: Listener) -> int:
    """Set ``runner`` up and listen at the listener's address; the port it bound. A taken port
    is a :class:`PortInUse` naming it (the runner cleaned up)."""
    await runner.setup()
    site = web.TCPSite(runner, listener.host, listener.port, reuse_address=True)
    try:
        await site.start()
    except OSError as exc:
        await runner.cleanup()
        raise as_port_error(listener, exc) from exc
    server = getattr(site, "_server", None)
    sockets = getattr(server, "sockets", None) or []
    port: int = sockets[0].getsockname()[1] if sockets else listener.port
    return port


def taken(all_listeners: Iterable[Listener]) -> PortInUse | None:
    """The listeners whose port another process holds now, tried the way the servers bind
    (asyncio's ``create_server``: every address of the host, ``SO_REUSEADDR``, IPv6 only on
    IPv6 sockets); None when every port is free. Port 0 (any free port) is never taken;
    other errors are left to the server, which reports them when it starts."""
    busy = [listener for listener in all_listeners
            if listener.port and _in_use(listener.host, listener.port)]
    return PortInUse(busy) if busy else None


def _in_use(host: str, port: int) -> bool:
    try:
        addresses = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM,
                                       flags=socket.AI_PASSIVE)
    except OSError:
        return False
    for family, kind, proto, _, address in addresses:
        with socket.socket(family, kind, proto) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            try:
                sock.bind(address)
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    return True
    return False
