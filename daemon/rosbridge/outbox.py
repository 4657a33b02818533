# Per-client outgoing queues: merged subscriptions, throttling, bounded latest-value queues.
from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from daemon.rosbridge.codec import Id, encode, publish_frame

EVENT_QUEUE = 100  # messages kept per event topic (every message counts) with queue_length 0
REPLY_QUEUE = 1024  # status and service replies kept for a client that is not reading


class SharedMessage:
    """One message for one topic, converted and JSON-encoded at most once for all clients."""

    __slots__ = ("_convert", "_frames", "_msg_json", "_source", "topic")

    def __init__(self, topic: str, source: Any,
                 convert: Callable[[Any], dict[str, Any]] | None = None) -> None:
        self.topic = topic
        self._source = source
        self._convert = convert
        self._msg_json: str | None = None
        self._frames: dict[str, str] = {}

    def msg_json(self) -> str:
        if self._msg_json is None:
            msg = self._convert(self._source) if self._convert else self._source
            self._msg_json = encode(msg)
            self._source = None
        return self._msg_json

    def frame(self, spelling: str) -> str:
        """The ``publish`` op for a subscriber that named the topic ``spelling``."""
        text = self._frames.get(spelling)
        if text is None:
            text = self._frames[spelling] = publish_frame(spelling, self.msg_json())
        return text


@dataclass(frozen=True)
class SubscribeOptions:
    """One ``subscribe`` request's options."""

    throttle_s: float = 0.0
    queue_length: int = 0
    fragment_size: int | None = None


class TopicQueue:
    """A client's subscription to one topic: its merged options and its bounded queue.

    Several subscriptions of one client merge as rosbridge merges them: the minimum
    throttle_rate, queue_length and fragment_size. ``queue_length`` 0 keeps only the latest
    message of a state topic (odometry, scans) and up to :data:`EVENT_QUEUE` of an event topic;
    with a throttle and no queue, messages inside the throttle window are dropped.
    """

    def __init__(self, topic: str, spelling: str, state: bool) -> None:
        self.topic = topic
        self.spelling = spelling
        self.state = state
        self.entries: dict[Id, SubscribeOptions] = {}
        self.options = SubscribeOptions()
        self.queue: deque[SharedMessage] = deque(maxlen=1)
        self.last_accept = -1e18
        self.next_send = 0.0
        self.dropped = 0

    def set_entry(self, key: Id, options: SubscribeOptions) -> None:
        self.entries[key] = options
        self._merge()

    def remove_entry(self, key: Id) -> None:
        self.entries.pop(key, None)
        if self.entries:
            self._merge()

    def _merge(self) -> None:
        entries = list(self.entries.values())
        sizes = [e.fragment_size for e in entries if e.fragment_size]
        self.options = SubscribeOptions(min(e.throttle_s for e in entries),
                                        min(e.queue_length for e in entries),
                                        min(sizes) if sizes else None)
        length = self.options.queue_length or (1 if self.state else EVENT_QUEUE)
        if self.queue.maxlen != length:
            self.queue = deque(self.queue, maxlen=length)

    def offer(self, message: SharedMessage, now: float) -> bool:
        """Queue ``message`` (runs inside the publisher: O(1), never blocks); False if dropped."""
        throttle = self.options.throttle_s
        if throttle > 0 and self.options.queue_length == 0:
            if now - self.last_accept < throttle:
                self.dropped += 1
                return False
            self.last_accept = now
        if len(self.queue) == self.queue.maxlen:
            self.dropped += 1
        self.queue.append(message)
        return True

    def take(self, now: float) -> tuple[SharedMessage | None, float | None]:
        """The next message to send now, or (None, seconds until one may be sent)."""
        if not self.queue:
            return None, None
        throttle = self.options.throttle_s
        if throttle > 0 and self.options.queue_length > 0:
            if now < self.next_send:
                return None, self.next_send - now
            self.next_send = now + throttle
        return self.queue.popleft(), None


class Outbox:
    """Everything waiting to go to one client: replies first, then topic queues in turn."""

    def __init__(self, wake: Callable[[], None],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.replies: deque[str] = deque(maxlen=REPLY_QUEUE)
        self.topics: dict[str, TopicQueue] = {}
        self.replies_dropped = 0
        self._wake = wake
        self._clock = clock
        self._turn = 0

    def reply(self, text: str) -> None:
        if len(self.replies) == self.replies.maxlen:
            self.replies_dropped += 1
        self.replies.append(text)
        self._wake()

    def offer(self, topic: str, message: SharedMessage) -> None:
        queue = self.topics.get(topic)
        if queue is not None and queue.offer(message, self._clock()):
            self._wake()

    def next_item(self) -> tuple[str | None, TopicQueue | None, SharedMessage | None,
                                 float | None]:
        """(reply) or (queue, message) ready now, else the delay until one may be ready."""
        if self.replies:
            return self.replies.popleft(), None, None, None
        now = self._clock()
        queues = list(self.topics.values())
        delay: float | None = None
        for i in range(len(queues)):
            queue = queues[(self._turn + i) % len(queues)]
            message, wait = queue.take(now)
            if message is not None:
                self._turn = (self._turn + i + 1) % len(queues)
                return None, queue, message, None
            if wait is not None:
                delay = wait if delay is None else min(delay, wait)
        return None, None, None, delay

    @property
    def dropped(self) -> int:
        return self.replies_dropped + sum(q.dropped for q in self.topics.values())
