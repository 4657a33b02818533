# The flight recorder's writer thread: MCAP files, chunk flushes, rotation and the disk cap.
from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

from mcap.writer import CompressionType, Writer

from daemon import __version__
from daemon.components.recorder.channels import Channel
from daemon.files import list_regular
from daemon.messages.msgtypes import full_text

log = logging.getLogger("arbiterd.recorder")

PREFIX = "arbiterd-"
SUFFIX = ".mcap"
RETRY_S = 10.0  # after a write error, try a new file this often
CAP_CHECK_S = 10.0
CHUNK_BYTES = 4 * 1024 * 1024  # chunks close on flush_interval_s long before this
COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
               "none": CompressionType.NONE}

Item = tuple[int, tuple[Channel, ...], Any]


@dataclass(frozen=True)
class WriterOptions:
    directory: Path
    max_file_bytes: int
    max_file_s: float
    max_total_bytes: int
    compression: str
    flush_interval_s: float
    queue_size: int


class OpenFile:
    """One MCAP file being written, with its channels registered. The writer holds an
    exclusive ``flock`` on it until it closes the file (or its process dies), which is how a
    reader in any process tells a file being recorded from one cut short."""

    def __init__(self, path: Path, compression: str, channels: Iterable[Channel],
                 metadata: dict[str, str]) -> None:
        self.path = path
        self.stream: IO[bytes] = path.open("xb")
        fcntl.flock(self.stream.fileno(), fcntl.LOCK_EX)  # a lister holds LOCK_SH only briefly
        self.ids: dict[str, int] = {}
        self.started = time.monotonic()
        self.sequence = 0
        # what the file holds so far (for listings while it is written: no need to read it)
        self.types: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        self.start_ns: int | None = None
        self.end_ns = 0
        try:
            self._begin(compression, channels, metadata)
        except OSError:
            self.stream.close()
            path.unlink(missing_ok=True)
            raise

    def _begin(self, compression: str, channels: Iterable[Channel],
               metadata: dict[str, str]) -> None:
        self.writer = Writer(self.stream, chunk_size=CHUNK_BYTES,
                             compression=COMPRESSION[compression])
        self.writer.start(profile="ros2", library=f"arbiterd {__version__}")
        schemas: dict[str, int] = {}
        for channel in channels:
            if channel.type not in schemas:
                schemas[channel.type] = self.writer.register_schema(
                    channel.type, "ros2msg", full_text(channel.type).encode())
            self.ids[channel.topic] = self.writer.register_channel(
                channel.topic, "cdr", schemas[channel.type])
            self.types[channel.topic] = channel.type
        self.writer.add_metadata("arbiterd", metadata)
        self.flush()

    def add(self, channel: Channel, log_time: int, data: bytes) -> None:
        self.sequence += 1
        self.writer.add_message(self.ids[channel.topic], log_time, data, log_time,
                                self.sequence)
        self.counts[channel.topic] = self.counts.get(channel.topic, 0) + 1
        if self.start_ns is None:
            self.start_ns = log_time
        self.end_ns = log_time

    def flush(self) -> None:
        """Close the chunk in progress and put it on the disk: a crash loses nothing before."""
        self.writer.flush()
        os.fsync(self.stream.fileno())

    def size(self) -> int:
        return self.stream.tell()

    def finish(self) -> None:
        """Summary and index, then close: the file is complete."""
        try:
            self.writer.finish()
            self.stream.flush()
            os.fsync(self.stream.fileno())
        finally:
            self.stream.close()

    def abandon(self) -> None:
        """Close after a write error; what reached the disk stays readable."""
        with contextlib.suppress(OSError):
            self.stream.close()


class FlightRecorder:
    """Takes messages from any thread in O(1) and writes them from its own thread.

    ``enqueue`` is all the tick and the command path ever do: a full queue drops and counts.
    The thread encodes (CDR), writes chunked MCAP, closes a chunk every ``flush_interval_s``,
    rotates by size and age, and keeps the directory under ``max_total_bytes`` by deleting the
    oldest recordings. An I/O error pauses recording with an error naming the path (health is
    degraded by the component) and a new file is tried every :data:`RETRY_S`.
    """

    def __init__(self, options: WriterOptions, channels: Iterable[Channel],
                 metadata: Callable[[], dict[str, str]] = dict,
                 on_open: Callable[[], list[tuple[tuple[Channel, ...], Any]]] = list) -> None:
        self.options = options
        self.channels = list(channels)
        self.metadata = metadata
        self.on_open = on_open
        #: set when recording is wanted or the writer stops: an idle writer sleeps until then
        self._nudge = threading.Event()
        self._wanted = False
        self.dropped = 0
        self.lost = 0
        self.written = 0
        self.bad = 0
        self.files_started = 0
        self.deleted = 0
        self.error: str | None = None
        #: bytes of the file being written (its chunks so far), updated by the writer thread
        self.file_bytes = 0
        self._queue: deque[Item] = deque()
        self._file: OpenFile | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="flight-recorder", daemon=True)
        self._wall0 = time.time_ns()
        self._mono0 = time.monotonic_ns()
        self._last_time = 0
        self._last_flush = 0.0
        self._last_cap = -CAP_CHECK_S
        self._retry_at = 0.0
        self._failed_channels: set[str] = set()

    # -- any thread -----------------------------------------------------------------------------

    @property
    def wanted(self) -> bool:
        """Whether the recorder should record (the thread opens or closes its file)."""
        return self._wanted

    @wanted.setter
    def wanted(self, wanted: bool) -> None:
        self._wanted = wanted
        if wanted:
            self._nudge.set()

    def enqueue(self, channels: tuple[Channel, ...], source: Any) -> None:
        """Hot path: stamp and queue; never blocks, never does I/O."""
        if not self._wanted:
            return
        if len(self._queue) >= self.options.queue_size:
            self.dropped += 1
            return
        self._queue.append((self._wall0 + time.monotonic_ns() - self._mono0, channels, source))

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        """Drain the queue, close the file with its summary, end the thread."""
        self._stop.set()
        self._nudge.set()
        if self._thread.is_alive():
            self._thread.join(timeout)

    @property
    def current(self) -> Path | None:
        file = self._file
        return file.path if file is not None else None

    def live_file(self) -> OpenFile | None:
        """The file being written (its counts are kept as messages are added)."""
        return self._file

    @property
    def queued(self) -> int:
        return len(self._queue)

    # -- the writer thread ------------------------------------------------------------------------

    def _run(self) -> None:
        poll = min(0.1, self.options.flush_interval_s / 2)
        while True:
            idle = not self._wanted and self._file is None and not self._queue
            if idle:  # nothing to write or close: sleep until wanted (no polling while off)
                self._nudge.wait()
                self._nudge.clear()
            stopping = self._stop.wait(0 if idle else poll)
            try:
                self._cycle(time.monotonic(), stopping)
            except Exception as exc:  # never let the thread die silently
                log.exception("flight recorder failed")
                self._fail(f"flight recorder failed: {exc}")
            if stopping:
                return

    def _cycle(self, now: float, stopping: bool) -> None:
        want = self.wanted and not stopping
        if want and self._file is None and now >= self._retry_at:
            self._open(now)
        self._drain()
        file = self._file
        if file is None:
            return
        if not want:
            self._close()
        elif now - self._last_flush >= self.options.flush_interval_s:
            self._last_flush = now
            try:
                file.flush()
            except OSError as exc:
                self._write_failed(file, exc)
                return
            self._maybe_rotate(now)
        if self._file is not None:
            self.file_bytes = self._file.size()
        if now - self._last_cap >= CAP_CHECK_S:
            self._enforce_cap()
            self._last_cap = now

    def _drain(self) -> None:
        items: list[Item] = []
        queue = self._queue
        while queue:
            items.append(queue.popleft())
        if not items:
            return
        if self._file is None:
            self.lost += len(items)
            return
        items.sort(key=lambda item: item[0])
        for t, channels, source in items:
            t = self._last_time = max(t, self._last_time)
            for channel in channels:
                data = self._encode(channel, source)
                file = self._file
                if data is None or file is None:
                    continue
                try:
                    file.add(channel, t, data)
                except OSError as exc:
                    self._write_failed(file, exc)
                else:
                    self.written += 1

    def _encode(self, channel: Channel, source: Any) -> bytes | None:
        try:
            return channel.cdr(source)
        except Exception as exc:
            self.bad += 1
            if channel.topic not in self._failed_channels:
                self._failed_channels.add(channel.topic)
                log.error("flight recorder: cannot encode a %s message: %s", channel.topic, exc)
            return None

    def _write_failed(self, file: OpenFile, exc: OSError) -> None:
        """Abandon the file (what reached the disk stays readable) and pause recording."""
        self._fail(f"cannot write {file.path}: {exc.strerror or exc}; recording paused (free "
                   f"some space or fix the permissions of {self.options.directory}, [recorder] "
                   f"directory); retrying every {RETRY_S:g} s")
        file.abandon()
        self._file = None

    def _fail(self, message: str) -> None:
        if message != self.error:
            log.error("%s", message)
        self.error = message
        self._retry_at = time.monotonic() + RETRY_S

    def _open(self, now: float) -> None:
        directory = self.options.directory
        try:
            directory.mkdir(parents=True, exist_ok=True)
            path = self._new_path()
            self._file = OpenFile(path, self.options.compression, self.channels,
                                   self.metadata())
        except OSError as exc:
            self._fail(f"cannot write recordings to {directory}: {exc.strerror or exc}; "
                       "recording paused (check that the directory exists, is writable by "
                       "the daemon and has free space; [recorder] directory); retrying every "
                       f"{RETRY_S:g} s")
            return
        if self.error is not None:
            log.warning("flight recorder: writing again (%s)", path)
        self.error = None
        self.files_started += 1
        self._last_flush = now
        log.info("flight recorder: writing %s", path)
        for channels, source in self.on_open():
            self.enqueue(channels, source)

    def _new_path(self) -> Path:
        """``arbiterd-20261122T141409_123Z.mcap``: fixed width, so names sort by start time."""
        ms = time.time_ns() // 1_000_000
        while True:
            when = datetime.fromtimestamp(ms / 1000, UTC)
            path = self.options.directory / (
                f"{PREFIX}{when:%Y%m%dT%H%M%S}_{ms % 1000:03d}Z{SUFFIX}")
            if not path.exists():
                return path
            ms += 1

    def _maybe_rotate(self, now: float) -> None:
        file = self._file
        if file is None:
            return
        if (file.size() >= self.options.max_file_bytes
                or now - file.started >= self.options.max_file_s):
            self._close()
            self._open(now)
            self._enforce_cap()

    def _close(self) -> None:
        """Finish the file, then forget it: ``current`` is None only once it is complete."""
        file = self._file
        if file is None:
            return
        try:
            file.finish()
            log.info("flight recorder: closed %s (%d bytes)", file.path, file.path.stat().st_size)
        except OSError as exc:
            self._fail(f"cannot finish {file.path}: {exc.strerror or exc}")
            file.abandon()
        finally:
            self._file = None

    def _enforce_cap(self) -> None:
        """Delete the oldest recordings until all of them fit in ``max_total_bytes``."""
        current = self.current
        try:
            files = sorted(recordings(self.options.directory), key=lambda p: p.name)
            sizes = {p: p.stat().st_size for p in files}
        except OSError:
            return
        total = sum(sizes.values())
        for path in files:
            if total <= self.options.max_total_bytes:
                break
            if path == current:
                continue
            try:
                path.unlink()
            except OSError as exc:
                log.warning("flight recorder: cannot delete %s: %s", path, exc)
                continue
            total -= sizes[path]
            self.deleted += 1
            log.info("flight recorder: deleted %s (disk cap %d MB)", path.name,
                     self.options.max_total_bytes // 1_000_000)

    # -- state -----------------------------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        return {"enabled": self.wanted, "recording": self._file is not None,
                "file": str(self.current) if self.current else None,
                "file_bytes": self.file_bytes if self._file is not None else None,
                "directory": str(self.options.directory), "written": self.written,
                "dropped": self.dropped, "lost": self.lost, "unencodable": self.bad,
                "queued": self.queued, "files_started": self.files_started,
                "deleted": self.deleted, "error": self.error}


def recordings(directory: Path) -> list[Path]:
    """The flight recorder's files in ``directory`` (nothing else there is touched): regular
    files only, never a symbolic link nor a FIFO (a link to /etc/passwd named like a
    recording would otherwise be listed, served and, past max_total_mb, counted); at most
    :data:`~daemon.files.MAX_LISTED` of them."""
    listing = list_regular(directory, lambda name: name.startswith(PREFIX) and
                           name.endswith(SUFFIX))
    return [directory / name for name, _, _ in listing.files]
