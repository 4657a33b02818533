# Files served, listed and written on request: regular files only, never through a link, bounded.
from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import stat
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from aiohttp import web

from daemon.security import Security, hide_paths
from daemon.web import ApiError, HttpPort

#: how a file is opened for reading: never through a symbolic link, never waiting on a FIFO
#: or a device (O_NONBLOCK: opening a FIFO with no writer returns at once)
READ_FLAGS = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
#: how a file is created: a new file, never through a link, never a FIFO's reader end
WRITE_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
#: the most entries one listing hands back, and the most directory entries it looks at
MAX_LISTED = 1000
MAX_SCANNED = 20_000


class FileRefused(OSError):
    """A file that is not served, listed or written: not a plain name, a link, not a regular
    file, or over a size cap. ``str()`` says which, without the directory's path."""


def plain_name(name: str) -> str:
    """``name`` when it names a file directly inside a directory (no ``/``, no ``..``)."""
    if not name or "/" in name or "\0" in name or name in (".", "..") or len(name) > 255:
        raise FileRefused(errno.EINVAL, f"{name[:80]!r} is not a plain file name")
    return name


def open_regular(directory: Path, name: str, max_bytes: int | None = None) -> BinaryIO:
    """``directory/name`` opened for reading, checked on the open descriptor (no race with a
    rename): a regular file of at most ``max_bytes``; :class:`FileRefused` otherwise (a
    symbolic link, a FIFO, a device, a socket, a directory)."""
    fd = os.open(directory / plain_name(name), READ_FLAGS)
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise FileRefused(errno.EINVAL, f"{name[:80]!r} is not a regular file")
        if max_bytes is not None and info.st_size > max_bytes:
            raise FileRefused(errno.EFBIG, f"{name[:80]!r} is {info.st_size} bytes, over the "
                              f"limit of {max_bytes}")
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_regular(directory: Path, name: str, max_bytes: int) -> bytes:
    """The whole of a regular file of at most ``max_bytes`` (:func:`open_regular`)."""
    with open_regular(directory, name, max_bytes) as file:
        data = file.read(max_bytes + 1)
    if len(data) > max_bytes:  # it grew after the check
        raise FileRefused(errno.EFBIG, f"{name[:80]!r} is over the limit of {max_bytes} bytes")
    return data


def read_head(directory: Path, name: str, size: int) -> bytes:
    """The first ``size`` bytes of a regular file (a header), whatever its length."""
    with open_regular(directory, name) as file:
        return file.read(size)


@dataclass
class Listing:
    """The regular files of a directory that a listing matched: (name, size, mtime) each,
    sorted by name; ``truncated`` when more were there than it looked at or hands back."""

    files: list[tuple[str, int, float]] = field(default_factory=list)
    truncated: bool = False

    @property
    def total_bytes(self) -> int:
        return sum(size for _, size, _ in self.files)


def list_regular(directory: Path, match: Callable[[str], bool],
                 limit: int = MAX_LISTED) -> Listing:
    """The regular files in ``directory`` whose names ``match``: links, FIFOs, devices and
    subdirectories are left out unopened; at most ``limit`` are handed back and at most
    :data:`MAX_SCANNED` entries looked at (a directory of a million files answers in bounded
    time). A missing directory lists nothing."""
    listing = Listing()
    try:
        scan = os.scandir(directory)
    except (FileNotFoundError, NotADirectoryError):
        return listing
    with scan:
        for seen, entry in enumerate(scan):
            if seen >= MAX_SCANNED or len(listing.files) >= limit:
                listing.truncated = True
                break
            if not match(entry.name) or not entry.is_file(follow_symlinks=False):
                continue
            try:
                info = entry.stat(follow_symlinks=False)
            except OSError:
                continue
            listing.files.append((entry.name, info.st_size, info.st_mtime))
    listing.files.sort()
    return listing


def write_atomically(directory: Path, name: str, data: bytes, *, max_bytes: int,
                     room: int | None = None) -> Path:
    """Write ``data`` as ``directory/name`` through a temporary file (a reader never sees
    half of it), never through a link nor into a FIFO left under the temporary name; refused
    (:class:`FileRefused`) over ``max_bytes``, or over ``room``: what the directory may still
    take."""
    plain_name(name)
    if len(data) > max_bytes:
        raise FileRefused(errno.EFBIG, f"{name!r} would be {len(data)} bytes, over the limit "
                          f"of {max_bytes}")
    if room is not None and len(data) > room:
        raise FileRefused(errno.ENOSPC, f"{name!r} ({len(data)} bytes) does not fit: "
                          f"{max(room, 0)} bytes of the directory's allowance are left")
    directory.mkdir(parents=True, exist_ok=True)
    partial = directory / f".{name}.partial"
    with contextlib.suppress(FileNotFoundError):  # whatever was left there (a FIFO, a
        partial.unlink()  # link): the entry goes, not what it points to
    fd = os.open(partial, WRITE_FLAGS, 0o644)
    with os.fdopen(fd, "wb") as file:
        file.write(data)
        file.flush()
        os.fsync(file.fileno())
    final = directory / name
    partial.replace(final)
    return final


# -- HTTP ------------------------------------------------------------------------------------

async def serve_file(http: HttpPort, request: web.Request, directory: Path, name: str,
                     content_type: str, missing: str) -> web.StreamResponse:
    """``directory/name`` as a download through :meth:`HttpPort.send_file` (the send
    deadline that cuts off a client that stops reading); 404 ``missing`` for anything
    :func:`open_regular` refuses, without saying why (nor where the directory is)."""
    try:
        file = await asyncio.to_thread(open_regular, directory, name)
    except OSError:  # missing, a link, a FIFO, a device, a name too long for the disk
        raise ApiError(404, missing) from None
    try:
        size = os.fstat(file.fileno()).st_size
        return await http.send_file(request, file, size, {
            "Content-Type": content_type,
            "Content-Disposition": f'attachment; filename="{name}"'})
    finally:
        file.close()


def shown(sees_paths: bool, value: Any) -> Any:
    """``value`` as a client is shown it: with every absolute path hidden unless it may see
    this machine's paths (``Security.sees_paths``)."""
    return value if sees_paths else hide_paths(value)


def sees_paths(security: Security, request: web.Request) -> bool:
    """Whether ``request`` may see this machine's paths (the token, when one is set)."""
    return security.sees_paths(request.headers, request.query, request.remote)
