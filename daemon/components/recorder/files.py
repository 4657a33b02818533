# Reading recordings back: duration, topics and counts of an MCAP file, complete or cut short.
from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from daemon.components.recorder.writer import recordings
from daemon.files import open_regular

if TYPE_CHECKING:
    from daemon.components.recorder.writer import OpenFile

MAGIC = b"\x89MCAP0\r\n"


@dataclass
class TopicInfo:
    type: str
    count: int = 0


@dataclass
class RecordingInfo:
    """What a recording holds. ``complete`` is False for a file being recorded (``recording``)
    and for one whose writer was killed: its messages up to the last whole chunk are there,
    but it has no summary or index (yet)."""

    name: str
    size: int
    complete: bool
    recording: bool = False
    start_ns: int | None = None
    end_ns: int | None = None
    topics: dict[str, TopicInfo] = field(default_factory=dict)

    @property
    def messages(self) -> int:
        return sum(t.count for t in self.topics.values())

    @property
    def duration_s(self) -> float:
        if self.start_ns is None or self.end_ns is None:
            return 0.0
        return (self.end_ns - self.start_ns) / 1e9

    def to_json(self, topics: bool = True) -> dict[str, Any]:
        body: dict[str, Any] = {
            "name": self.name, "size": self.size, "complete": self.complete,
            "recording": self.recording,
            "start": None if self.start_ns is None else self.start_ns / 1e9,
            "duration_s": round(self.duration_s, 3), "messages": self.messages}
        if topics:
            body["topics"] = {name: {"type": t.type, "count": t.count}
                              for name, t in sorted(self.topics.items())}
        return body


def inspect(path: Path) -> RecordingInfo:
    """Read ``path``'s summary, or scan it record by record when it is being recorded or was
    cut short."""
    with open_regular(path.parent, path.name) as stream:
        size = os.fstat(stream.fileno()).st_size
        recording = being_recorded(stream)
        if not recording and _ends_with_magic(stream, size):
            info = _from_summary(path.name, size, stream)
            if info is not None:
                return info
        stream.seek(0)
        info = _salvage(path.name, size, stream)
        info.recording = recording
        return info


def being_recorded(stream: IO[bytes]) -> bool:
    """A writer (in any process) holds the file's exclusive lock: it is being recorded."""
    try:
        fcntl.flock(stream.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:  # a file system without flock: nothing to tell
        return False
    fcntl.flock(stream.fileno(), fcntl.LOCK_UN)
    return False


def _ends_with_magic(stream: IO[bytes], size: int) -> bool:
    if size < 2 * len(MAGIC):
        return False
    stream.seek(size - len(MAGIC))
    return stream.read(len(MAGIC)) == MAGIC


def _from_summary(name: str, size: int, stream: IO[bytes]) -> RecordingInfo | None:
    stream.seek(0)
    try:
        summary = make_reader(stream).get_summary()
    except Exception:
        return None
    if summary is None or summary.statistics is None:
        return None
    stats = summary.statistics
    info = RecordingInfo(name, size, True)
    if stats.message_count:
        info.start_ns, info.end_ns = stats.message_start_time, stats.message_end_time
    for channel_id, channel in summary.channels.items():
        schema = summary.schemas.get(channel.schema_id)
        info.topics[channel.topic] = TopicInfo(
            schema.name if schema else "", stats.channel_message_counts.get(channel_id, 0))
    return info


def _salvage(name: str, size: int, stream: IO[bytes]) -> RecordingInfo:
    info = RecordingInfo(name, size, False)
    schemas: dict[int, str] = {}
    channels: dict[int, TopicInfo] = {}
    with contextlib.suppress(Exception):  # the first broken record ends what can be read
        for record in StreamReader(stream, skip_magic=False).records:
            if isinstance(record, Schema):
                schemas[record.id] = record.name
            elif isinstance(record, Channel):
                channels[record.id] = info.topics.setdefault(
                    record.topic, TopicInfo(schemas.get(record.schema_id, "")))
            elif isinstance(record, Message) and record.channel_id in channels:
                channels[record.channel_id].count += 1
                t = record.log_time
                info.start_ns = t if info.start_ns is None else min(info.start_ns, t)
                info.end_ns = t if info.end_ns is None else max(info.end_ns, t)
    return info


def _live_info(file: OpenFile) -> RecordingInfo:
    info = RecordingInfo(file.path.name, file.path.stat().st_size, False, True, file.start_ns,
                         file.end_ns if file.start_ns is not None else None)
    counts = dict(file.counts)
    info.topics = {topic: TopicInfo(type_name, counts.get(topic, 0))
                   for topic, type_name in file.types.items()}
    return info


class RecordingIndex:
    """The recordings of a directory, each file read once per (size, mtime)."""

    def __init__(self, directory: Path,
                 live: Callable[[], OpenFile | None] = lambda: None) -> None:
        self.directory = directory
        self.live = live
        self._cache: dict[Path, tuple[tuple[int, int], RecordingInfo]] = {}

    def list(self) -> list[RecordingInfo]:
        """Every recording; the one being written is described from the writer's counts."""
        live = self.live()
        out = []
        for path in sorted(recordings(self.directory), key=lambda p: p.name):
            with contextlib.suppress(OSError):
                out.append(_live_info(live) if live is not None and live.path == path
                           else self.info(path))
        self._cache = {p: v for p, v in self._cache.items() if p.exists()}
        return out

    def info(self, path: Path) -> RecordingInfo:
        stat = path.stat()
        key = (stat.st_size, stat.st_mtime_ns)
        cached = self._cache.get(path)
        if cached is not None and cached[0] == key:
            return cached[1]
        info = inspect(path)
        if not info.recording:  # its writer may die without changing size or time
            self._cache[path] = (key, info)
        return info
