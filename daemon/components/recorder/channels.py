# What the flight recorder writes: one MCAP channel per recorded topic of the topic table.
from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from daemon.messages import cdr
from daemon.messages.scans import BINARY_CDR
from daemon.topics import TopicOut


@dataclass(frozen=True)
class Channel:
    """One recorded topic: its ROS 2 type and how a bus message becomes that message."""

    topic: str
    type: str
    convert: Callable[[Any], dict[str, Any]]

    def cdr(self, source: Any) -> bytes:
        direct = BINARY_CDR.get(self.type)  # a CDR encoder of its own (scans)
        if direct is not None:
            return direct(source)
        return cdr.encode(self.type, self.convert(source))


def channel(topic: TopicOut[Any]) -> Channel:
    return Channel(topic.name, topic.type, topic.convert)


def channels_by_bus(topics: Iterable[TopicOut[Any]]) -> dict[str, tuple[Channel, ...]]:
    """Bus key name => the channels its messages are recorded on (``odom`` feeds /odom and
    /tf: one queue entry, two channels)."""
    groups: dict[str, list[Channel]] = {}
    for topic in topics:
        groups.setdefault(topic.bus.name, []).append(channel(topic))
    return {name: tuple(group) for name, group in groups.items()}
