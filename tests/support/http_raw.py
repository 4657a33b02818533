# Raw HTTP/1.1 over real sockets for the hardening tests: exact bytes out, parsed answers back.
from __future__ import annotations

import asyncio
import json
import resource
import select
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

LOCAL = "127.0.0.1"


@dataclass
class Answer:
    status: int
    headers: dict[str, str]
    body: bytes

    def json(self) -> Any:
        return json.loads(self.body)

    def is_json_error(self) -> bool:
        """The documented error shape: a JSON object with ``error`` and ``detail``."""
        if not self.headers.get("content-type", "").startswith("application/json"):
            return False
        try:
            body = self.json()
        except ValueError:
            return False
        return isinstance(body, dict) and set(body) == {"error", "detail"}


def request(method: str, path: str, port: int, body: bytes = b"", *,
            headers: dict[str, str] | None = None, host: str | None = None) -> bytes:
    """The bytes of one ``Connection: close`` request (``Content-Length`` when a body)."""
    lines = [f"{method} {path} HTTP/1.1", f"Host: {host or f'{LOCAL}:{port}'}",
             "Connection: close"]
    all_headers = {"Content-Type": "application/json"} if body else {}
    all_headers.update(headers or {})
    if body and "Transfer-Encoding" not in all_headers:
        all_headers.setdefault("Content-Length", str(len(body)))
    lines += [f"{k}: {v}" for k, v in all_headers.items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode() + body


def parse_answer(data: bytes, head_only: bool = False) -> Answer | None:
    """The answer in ``data`` when it is complete, else ``None``."""
    head, sep, body = data.partition(b"\r\n\r\n")
    if not sep:
        return None
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    headers = {}
    for line in lines[1:]:
        name, _, value = line.partition(":")
        headers[name.strip().lower()] = value.strip()
    length = 0 if head_only else int(headers.get("content-length", "0"))
    if len(body) < length:
        return None
    return Answer(status, headers, body[:length])


def connect(port: int) -> socket.socket:
    sock = socket.create_connection((LOCAL, port), timeout=5)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def read_answer(sock: socket.socket, within_s: float = 5.0, head_only: bool = False) -> Answer:
    """Read until one whole answer is in (or fail after ``within_s``)."""
    sock.settimeout(within_s)
    data = b""
    while (answer := parse_answer(data, head_only)) is None:
        chunk = sock.recv(65536)
        if not chunk:
            raise AssertionError(f"connection closed before a whole answer: {data[:200]!r}")
        data += chunk
    return answer


def exchange(port: int, data: bytes, within_s: float = 5.0, head_only: bool = False) -> Answer:
    """Send ``data`` on a new connection and read the answer."""
    with connect(port) as sock:
        sock.sendall(data)
        return read_answer(sock, within_s, head_only)


def quiet_for(sock: socket.socket, seconds: float) -> bool:
    """Nothing arrives on ``sock`` for ``seconds`` (no answer, no close)."""
    readable, _, _ = select.select([sock], [], [], seconds)
    return not readable


def closed_by_peer(sock: socket.socket, within_s: float) -> bool:
    """The server closes ``sock`` (EOF or reset) within ``within_s``, sending nothing."""
    sock.settimeout(within_s)
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False


async def send_raw(port: int, parts: list[bytes], read_s: float,
                   pause_s: float = 0.0) -> bytes:
    """Send ``parts`` (as separate writes) and collect what comes back until the first whole
    answer, the server closing, or ``read_s``."""
    try:
        reader, writer = await asyncio.open_connection(LOCAL, port)
    except OSError:
        return b""
    data = b""
    try:
        for part in parts:
            writer.write(part)
            await writer.drain()
            if pause_s:
                await asyncio.sleep(pause_s)
        async with asyncio.timeout(read_s):
            head = b"".join(parts).startswith(b"HEAD ")
            while parse_answer(data, head) is None and (chunk := await reader.read(65536)):
                data += chunk
    except (TimeoutError, ConnectionError):
        pass
    finally:
        writer.close()
    return data


def drip_is_refused(sock: socket.socket) -> bool:
    """Send one more header byte; true once the server has closed the connection."""
    try:
        sock.sendall(b"X")
    except OSError:
        return True
    return not quiet_for(sock, 0.1) and closed_by_peer(sock, 0.1)


def stalled_download(port: int, recording: str, path: str = "") -> socket.socket:
    """A tokenless client that asks for a (large) recording (or any file at ``path``), reads
    the answer's first bytes and never reads again: the server's handler stays blocked on
    the socket."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connect: a small window
    sock.settimeout(5)
    sock.connect((LOCAL, port))
    sock.sendall(request("GET", path or f"/api/recordings/{recording}", port))
    head = sock.recv(1024)
    assert head.startswith(b"HTTP/1.1 200"), head[:200]
    return sock


@contextmanager
def child_nofile(limit: int) -> Iterator[None]:
    """Processes started inside inherit a soft ``RLIMIT_NOFILE`` of ``limit``; this process
    gets as many as it may afterwards (it opens the client sockets)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(limit, hard), hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, min(hard, 8192)), hard))


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmRSS for pid {pid}")
