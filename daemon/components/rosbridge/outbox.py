# Per-client outgoing queues: merged subscriptions, throttling, bounded queues, O(1) scheduling.
from __future__ import annotations

import heapq
import itertools
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from daemon.components.rosbridge import binary
from daemon.components.rosbridge.codec import Id, encode, fragment_count, fragments, publish_frame
from daemon.messages import cbor, cdr, scans
from daemon.messages.convert import JSON_CONVERT, JSON_TEXT

EVENT_QUEUE = 100  # messages kept per event topic (every message counts) with queue_length 0
REPLY_QUEUE = 1024  # status and service replies kept for a client that is not reading
REPLY_BYTES = 8 * 1048576  # ... and at most this much of them (the oldest go first)


class SharedMessage:
    """One message for one topic, converted and encoded at most once per encoding (JSON, cbor,
    cbor-raw) for all clients; ``source`` is the robot's own data when ``convert`` is given,
    else a message dict."""

    __slots__ = ("_binary_frames", "_binary_msgs", "_convert", "_frames", "_msg_json",
                 "_source", "topic")

    def __init__(self, topic: str, source: Any,
                 convert: Callable[[Any], dict[str, Any]] | None = None) -> None:
        self.topic = topic
        self._source = source
        self._convert = convert
        self._msg_json: str | None = None
        self._frames: dict[str, str] = {}
        self._binary_msgs: dict[str, bytes] = {}
        self._binary_frames: dict[tuple[str, str], bytes] = {}

    def msg_json(self) -> str:
        if self._msg_json is None:
            convert = self._convert  # for JSON, a faster conversion when there is one (scans)
            text = JSON_TEXT.get(convert) if convert is not None else None
            if text is not None:  # straight to the text (latency reports)
                self._msg_json = text(self._source)
            else:
                self._msg_json = encode(self._source if convert is None
                                        else convert_for_json(convert)(self._source))
        return self._msg_json

    def binary_frame(self, compression: str, spelling: str, type_name: str) -> bytes:
        """The binary ``publish`` frame (``cbor`` or ``cbor-raw``) of this message as
        ``type_name``; raises :class:`cdr.CdrError` when the message does not fit the type."""
        key = (compression, spelling)
        frame = self._binary_frames.get(key)
        if frame is None:
            frame = self._binary_frames[key] = binary.publish_frame(
                spelling, self._binary_msg(compression, type_name))
        return frame

    def _binary_msg(self, compression: str, type_name: str) -> bytes:
        msg = self._binary_msgs.get(compression)
        if msg is None:
            if compression == "cbor":
                msg = cbor.cbor_msg(type_name, self._values(type_name))
            else:  # the server clock at (first) send, as rosbridge's cbor-raw carries it
                msg = binary.cbor_raw_msg(self._cdr(type_name), time.time())
            self._binary_msgs[compression] = msg
        return msg

    def _values(self, type_name: str) -> Any:
        """The message as a dict for the binary encoders (robot data: their own conversion)."""
        if self._convert is None:
            return self._source
        return scans.BINARY_CONVERT.get(type_name, self._convert)(self._source)

    def _cdr(self, type_name: str) -> bytes:
        direct = scans.BINARY_CDR.get(type_name) if self._convert is not None else None
        if direct is not None:
            return direct(self._source)
        return cdr.encode(type_name, self._values(type_name))

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
    compression: str = "none"


#: rosbridge's precedence when one client's subscriptions to a topic ask for different ones
COMPRESSION_PRECEDENCE = ("none", "png", "cbor", "cbor-raw")


class MinTracker:
    """The minimum of a multiset of numbers: O(log n) add and remove (a heap with lazy
    deletion, compacted when stale entries pile up)."""

    def __init__(self) -> None:
        self._heap: list[float] = []
        self._counts: Counter[float] = Counter()

    def add(self, value: float) -> None:
        if not self._counts[value]:
            heapq.heappush(self._heap, value)
        self._counts[value] += 1

    def remove(self, value: float) -> None:
        self._counts[value] -= 1
        if self._counts[value] <= 0:
            del self._counts[value]
            if len(self._heap) > 2 * len(self._counts) + 8:
                self._heap = list(self._counts)
                heapq.heapify(self._heap)

    def min(self) -> float | None:
        while self._heap and self._heap[0] not in self._counts:
            heapq.heappop(self._heap)
        return self._heap[0] if self._heap else None


class TopicQueue:
    """A client's subscription to one topic: its merged options and its bounded queue.

    Several subscriptions of one client merge as rosbridge merges them: the minimum
    throttle_rate, queue_length and fragment_size (kept in O(log n) per change). With
    ``queue_length`` 0 a state topic (odometry, scans) keeps only the latest message and an
    event topic up to :data:`EVENT_QUEUE`; with a throttle and no queue, messages inside the
    throttle window are dropped.
    """

    def __init__(self, topic: str, spelling: str, state: bool, type_name: str = "") -> None:
        self.topic = topic
        self.spelling = spelling
        self.state = state
        self.type_name = type_name  # what binary encodings serialise the messages as
        self.entries: dict[Id, SubscribeOptions] = {}
        self.options = SubscribeOptions()
        #: a message is sent as one JSON text as soon as it may (no throttle, no fragments,
        #: no binary encoding): kept with the options, read for every message offered
        self.plain = True
        self.queue: deque[SharedMessage] = deque(maxlen=1)
        self.last_accept = -1e18
        self.next_send = 0.0
        self.dropped = 0
        self.scheduled = False  # in the outbox's ready or waiting line
        self.closed = False
        self._throttle, self._length, self._fragment = MinTracker(), MinTracker(), MinTracker()
        self._compressions: Counter[str] = Counter()

    def set_entry(self, key: Id, options: SubscribeOptions) -> None:
        old = self.entries.get(key)
        if old is not None:
            self._untrack(old)
        self.entries[key] = options
        self._throttle.add(options.throttle_s)
        self._length.add(options.queue_length)
        if options.fragment_size:
            self._fragment.add(options.fragment_size)
        self._compressions[options.compression] += 1
        self._merge()

    def remove_entry(self, key: Id) -> None:
        old = self.entries.pop(key, None)
        if old is not None:
            self._untrack(old)
        if self.entries:
            self._merge()

    def _untrack(self, options: SubscribeOptions) -> None:
        self._throttle.remove(options.throttle_s)
        self._length.remove(options.queue_length)
        if options.fragment_size:
            self._fragment.remove(options.fragment_size)
        self._compressions[options.compression] -= 1

    def _compression(self) -> str:
        """rosbridge's precedence over this client's subscriptions: cbor-raw > cbor > png."""
        return next((c for c in reversed(COMPRESSION_PRECEDENCE) if self._compressions[c] > 0),
                    "none")

    def _merge(self) -> None:
        fragment = self._fragment.min()
        self.options = SubscribeOptions(self._throttle.min() or 0.0,
                                        int(self._length.min() or 0),
                                        int(fragment) if fragment else None,
                                        self._compression())
        options = self.options
        self.plain = options.throttle_s == 0 and options.fragment_size is None \
            and options.compression == "none"
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


class FragmentedReply:
    """A reply sent in ``fragment`` ops, made lazily piece by piece by the writer."""

    def __init__(self, text: str, size: int, fragment_id: str | int) -> None:
        self.text = text
        self.size = size
        self.fragment_id = fragment_id

    def __len__(self) -> int:
        return len(self.text)

    @property
    def count(self) -> int:
        return fragment_count(self.text, self.size)

    def pieces(self) -> Iterator[str]:
        return fragments(self.text, self.size, self.fragment_id)


Reply = str | FragmentedReply


class Outbox:
    """Everything waiting to go to one client: replies first, then the topic queues that have
    a message, in turn. Finding the next message is O(1): a queue joins the ready line when
    it gets a message and a throttled one waits in a heap until it may send again."""

    def __init__(self, wake: Callable[[], None],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.replies: deque[Reply] = deque()
        self.reply_bytes = 0
        self.topics: dict[str, TopicQueue] = {}
        self.replies_dropped = 0
        self._wake = wake
        self._clock = clock
        self._ready: deque[TopicQueue] = deque()
        self._waiting: list[tuple[float, int, TopicQueue]] = []
        self._order = itertools.count()
        #: set while the client's reader handles a request and sends what it queued itself
        #: right after (see :meth:`hold`)
        self.holding = False
        self._held: tuple[TopicQueue, SharedMessage] | None = None
        #: while holding: writes the answer to the socket at once; False when it cannot
        self.send_now: Callable[[TopicQueue, SharedMessage], bool] | None = None

    def hold(self) -> None:
        """The reader handles a request: the first topic message it brings while nothing
        else waits (the answer to a command) is kept aside for :meth:`take_held` instead of
        going through its queue, as long as nothing else comes; anything else that comes
        first puts it in its queue, where it would have been."""
        self.holding = True

    def take_held(self) -> tuple[TopicQueue, SharedMessage] | None:
        """Ends :meth:`hold`: the message kept aside, if any, for the caller to send now
        (or to give back with :meth:`requeue`)."""
        self.holding = False
        held, self._held = self._held, None
        return held if held is not None and not held[0].closed else None

    def requeue(self, held: tuple[TopicQueue, SharedMessage]) -> None:
        """A held message that could not be sent at once: into its queue after all."""
        queue, message = held
        if not queue.closed and queue.offer(message, self._clock()):
            self._schedule(queue)
            self._wake()

    def _release(self) -> None:
        held, self._held = self._held, None
        if held is not None:
            self.requeue(held)

    def reply(self, item: Reply) -> None:
        if self._held is not None:
            self._release()
        self.replies.append(item)
        self.reply_bytes += len(item)
        while len(self.replies) > 1 and (len(self.replies) > REPLY_QUEUE
                                         or self.reply_bytes > REPLY_BYTES):
            self.reply_bytes -= len(self.replies.popleft())
            self.replies_dropped += 1
        self._wake()

    def offer(self, topic: str, message: SharedMessage) -> None:
        queue = self.topics.get(topic)
        if queue is None:
            return
        if self.holding:
            if self._held is None and not self.replies and not self._ready \
                    and not self._waiting and not queue.queue and queue.plain:
                send_now = self.send_now
                if send_now is None or not send_now(queue, message):
                    self._held = (queue, message)  # the answer: sent by the reader, or queued
                return
            self._release()
        if queue.offer(message, self._clock()):
            self._schedule(queue)
            self._wake()

    def add_queue(self, queue: TopicQueue) -> None:
        self.topics[queue.topic] = queue

    def drop_queue(self, topic: str) -> None:
        queue = self.topics.pop(topic, None)
        if queue is None:
            return
        queue.closed = True
        if len(self._ready) > 2 * len(self.topics) + 16:
            self._ready = deque(q for q in self._ready if not q.closed)
        if len(self._waiting) > 2 * len(self.topics) + 16:
            self._waiting = [entry for entry in self._waiting if not entry[2].closed]
            heapq.heapify(self._waiting)

    def clear(self) -> None:
        """Drop every subscription queue (the client is gone)."""
        for queue in self.topics.values():
            queue.closed = True
        self._held = None
        self.topics.clear()
        self._ready.clear()
        self._waiting.clear()

    def _schedule(self, queue: TopicQueue) -> None:
        if not queue.scheduled and not queue.closed:
            queue.scheduled = True
            self._ready.append(queue)

    def has_ready(self) -> bool:
        """Whether :meth:`next_item` may have something now (cheap: no queue is touched)."""
        return bool(self._held or self.replies or self._ready
                    or (self._waiting and self._waiting[0][0] <= self._clock()))

    def next_item(self) -> tuple[Reply | None, TopicQueue | None, SharedMessage | None,
                                 float | None]:
        """(reply) or (queue, message) ready now, else the delay until one may be ready."""
        if self._held is not None:
            self._release()
        if self.replies:
            item = self.replies.popleft()
            self.reply_bytes -= len(item)
            return item, None, None, None
        now = self._clock()
        while self._waiting and self._waiting[0][0] <= now:
            self._ready.append(heapq.heappop(self._waiting)[2])
        while self._ready:
            queue = self._ready.popleft()
            message, wait = queue.take(now) if not queue.closed else (None, None)
            if message is not None:
                if queue.queue:
                    self._ready.append(queue)
                else:
                    queue.scheduled = False
                return None, queue, message, None
            if wait is not None:
                heapq.heappush(self._waiting, (now + wait, next(self._order), queue))
            else:
                queue.scheduled = False
        delay = self._waiting[0][0] - now if self._waiting else None
        return None, None, None, delay

    @property
    def dropped(self) -> int:
        return self.replies_dropped + sum(q.dropped for q in self.topics.values())


def convert_for_json(convert: Callable[[Any], dict[str, Any]]) -> Callable[[Any], dict[str, Any]]:
    """The conversion to use when the message only becomes JSON text."""
    return JSON_CONVERT.get(convert, convert)
