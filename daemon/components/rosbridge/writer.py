# One client's outgoing side: drains its outbox to the socket, fragments in paced slices.
from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Iterator

from aiohttp import web

from daemon.components.rosbridge.binary import BINARY_COMPRESSIONS
from daemon.components.rosbridge.codec import Id, fragment_count, fragments, over_limit
from daemon.components.rosbridge.limits import Limits, Pacer
from daemon.components.rosbridge.outbox import FragmentedReply, Outbox, SharedMessage, TopicQueue
from daemon.messages.cdr import CdrError

log = logging.getLogger("arbiterd.rosbridge")

INLINE_SENDS = 4  # most messages the reader sends itself after one request
SLICE = 32  # fragments sent between yields to the event loop

Warn = Callable[[str, str, Id], None]  # (key, message, id): a status error, once per key


class Writer:
    """Sends what the outbox holds: replies first, then topic messages in turn. One sender
    at a time (its own task, or the reader inline), so fragments never interleave."""

    def __init__(self, ws: web.WebSocketResponse, outbox: Outbox, limits: Limits,
                 pacer: Pacer, warn: Warn) -> None:
        self.ws = ws
        self.outbox = outbox
        self.limits = limits
        self.pacer = pacer
        self.warn = warn
        self._sending = asyncio.Lock()
        self._wakeup = asyncio.Event()
        self._idle = False
        self._next_delay: float | None = None
        #: the reader is handling a request and sends what it queued itself (send_inline):
        #: waking the writer task for it would only cost a task switch
        self.inline = False
        self._transport: asyncio.WriteTransport | None = None
        self._compressed: bool | None = None  # permessage-deflate: fixed at the handshake

    def wake(self) -> None:
        if not self.inline:
            self._wakeup.set()

    async def run(self) -> None:
        """Send until the socket fails; sleep while nothing is ready."""
        try:
            while True:
                if not await self._send_next():
                    self._wakeup.clear()
                    self._idle = True
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(self._wakeup.wait(), self._next_delay)
                    self._idle = False
        except (ConnectionError, RuntimeError) as exc:
            log.debug("rosbridge writer stopped: %s", exc)

    def begin_inline(self, transport: asyncio.BaseTransport | None = None) -> None:
        """The reader handles a request and then calls :meth:`send_inline`: the writer task
        is not woken for what the request queues, and the outbox holds its answer aside, or
        with ``transport`` writes it at once when nothing else is on its way (:meth:`_now`)."""
        self.inline = True
        self.outbox.hold()
        if isinstance(transport, asyncio.WriteTransport):
            self._transport = transport
            self.outbox.send_now = self._now

    def _now(self, queue: TopicQueue, message: SharedMessage) -> bool:
        """Write the request's answer to the socket from inside its publisher (the command's
        latency report from the control loop), when nothing else is on its way: the writer
        task sleeps, no send is under way, the socket holds nothing unsent, the connection
        is open and uncompressed. False: the outbox holds it as before."""
        transport, ws = self._transport, self.ws
        compressed = self._compressed
        if compressed is None:
            compressed = self._compressed = bool(getattr(ws, "compress", True))
        if not self._idle or compressed or self._sending.locked() or ws.closed \
                or getattr(ws, "_closing", True) or transport is None \
                or transport.is_closing() or transport.get_write_buffer_size():
            return False
        transport.write(text_frame(message.frame(queue.spelling).encode()))
        return True

    async def send_inline(self, transport: asyncio.BaseTransport | None) -> None:
        """Answer from the reader while the writer sleeps and the socket takes data at once:
        saves the hop to the writer task on the command -> report path (and the answer the
        outbox held aside skips its queue). Ends :attr:`inline`: the writer task is woken for
        whatever is left."""
        self.inline = False
        self.outbox.send_now = None
        held = self.outbox.take_held()
        try:
            if self._idle and not self._sending.locked() and transport is not None \
                    and not _buffered(transport):
                sends = INLINE_SENDS
                if held is not None:
                    queue, message = held
                    held = None
                    await self._send_held(queue, message)
                    sends -= 1
                for _ in range(sends):
                    if not self.outbox.has_ready() or not await self._send_next():
                        break
        except (ConnectionError, RuntimeError) as exc:
            log.debug("rosbridge inline send failed: %s", exc)
        finally:
            if held is not None:
                self.outbox.requeue(held)
            if self.outbox.has_ready():
                self._wakeup.set()

    async def _send_held(self, queue: TopicQueue, message: SharedMessage) -> None:
        """What :meth:`_send_next` does with a message of a plain queue, without the queue."""
        sending = self._sending
        await sending.acquire()
        try:
            await self.ws.send_str(message.frame(queue.spelling))
        finally:
            sending.release()

    async def _send_next(self) -> bool:
        """Send one queued reply or message; False when nothing is ready now."""
        sending = self._sending  # acquire/release: `async with` costs two more coroutines
        await sending.acquire()
        try:
            item, queue, message, self._next_delay = self.outbox.next_item()
            if isinstance(item, FragmentedReply):
                await self.send_pieces(item.pieces())
            elif item is not None:
                await self.ws.send_str(item)
            elif queue is not None and message is not None:
                await self._send_topic(queue, message)
            else:
                return False
            return True
        finally:
            sending.release()

    async def send_pieces(self, pieces: Iterator[str]) -> None:
        """Fragments in slices paced by the shared fragment rate, yielding to the event loop
        between them: a message cut into a million pieces costs the loop short slices."""
        for count, piece in enumerate(pieces):
            if count % SLICE == 0:
                await self.pacer.take(SLICE)
                await asyncio.sleep(0)
            await self.ws.send_str(piece)

    async def _send_topic(self, queue: TopicQueue, message: SharedMessage) -> None:
        compression = queue.options.compression
        if compression in BINARY_COMPRESSIONS:
            await self._send_binary(queue, message, compression)
            return
        text = message.frame(queue.spelling)
        size = queue.options.fragment_size
        if not size or len(text) <= size:
            await self.ws.send_str(text)
            return
        count = fragment_count(text, size)
        if count > self.limits.max_fragments_per_message:
            queue.dropped += 1
            refusal = over_limit(f"subscribe {queue.topic}: a message needs {count} fragments "
                                 f"of {size}; dropped", self.limits.max_fragments_per_message,
                                 "max_fragments_per_message")
            self.warn(f"fragments:{queue.topic}", refusal.message, None)
            return
        await self.send_pieces(fragments(text, size, f"publish:{queue.spelling}:{id(message)}"))

    async def _send_binary(self, queue: TopicQueue, message: SharedMessage,
                           compression: str) -> None:
        """One binary frame (``cbor`` or ``cbor-raw``), shared with every subscriber of the
        message, never fragmented (rosbridge's fragment_size applies to JSON only)."""
        try:
            data = message.binary_frame(compression, queue.spelling, queue.type_name)
        except CdrError as exc:
            queue.dropped += 1
            self.warn(f"{compression}:{queue.topic}", f"subscribe {queue.topic}: a message "
                      f"cannot be sent as {compression}: {exc}; dropped", None)
            return
        await self.ws.send_bytes(data)


def text_frame(payload: bytes) -> bytes:
    """One WebSocket text frame as a server sends it (RFC 6455 5.2): final, unmasked,
    uncompressed, the payload length in 7, 16 or 64 bits."""
    length = len(payload)
    if length < 126:
        head = bytes((0x81, length))
    elif length < 65536:
        head = bytes((0x81, 126)) + length.to_bytes(2, "big")
    else:
        head = bytes((0x81, 127)) + length.to_bytes(8, "big")
    return head + payload


def _buffered(transport: asyncio.BaseTransport) -> int:
    """Bytes the transport still holds (1 when it cannot tell: then nothing is sent inline)."""
    size = getattr(transport, "get_write_buffer_size", None)
    return size() if size is not None else 1
