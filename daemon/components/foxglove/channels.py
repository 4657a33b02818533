# The server's channels: one per outgoing topic of the topic table (ros2msg schema, CDR data).
from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from daemon.messages import cdr
from daemon.messages.msgtypes import full_text
from daemon.messages.scans import BINARY_CDR, BINARY_CONVERT
from daemon.topics import TopicOut


@dataclass(frozen=True)
class Channel:
    """One outgoing topic as a Foxglove channel."""

    id: int
    topic: TopicOut[Any]

    def advertisement(self) -> dict[str, Any]:
        return {"id": self.id, "topic": self.topic.name, "encoding": "cdr",
                "schemaName": self.topic.type, "schemaEncoding": "ros2msg",
                "schema": full_text(self.topic.type)}


class Outgoing:
    """One bus message of a channel, serialised to CDR at most once for every client (by
    the first client's writer, after the control tick that published it)."""

    __slots__ = ("_cdr", "_source", "channel", "t_ns")

    def __init__(self, channel: Channel, source: Any) -> None:
        self.channel = channel
        self._source = source
        self._cdr: bytes | None = None
        #: receive time (the bus publish), as the protocol's message timestamp
        self.t_ns = time.time_ns()

    def cdr(self) -> bytes:
        """The message as CDR (encapsulation header included); :class:`cdr.CdrError` when
        the robot's data does not fit its type."""
        if self._cdr is None:
            topic = self.channel.topic
            direct = BINARY_CDR.get(topic.type)
            if direct is not None:
                self._cdr = direct(self._source)
            else:
                convert = BINARY_CONVERT.get(topic.type, topic.convert)
                self._cdr = cdr.encode(topic.type, convert(self._source))
        return self._cdr


def channels(topics: Iterable[TopicOut[Any]]) -> dict[int, Channel]:
    """Every outgoing topic, numbered from 1 in the table's order."""
    return {i: Channel(i, topic) for i, topic in enumerate(topics, start=1)}
