# Refuses WebSocket frames a client sent unmasked (RFC 6455 5.1), which aiohttp accepts.
from __future__ import annotations

from collections.abc import Callable
from typing import Any

from aiohttp import WebSocketError, WSCloseCode

REFUSED = (True, b"")


class MaskGate:
    """Stands in front of aiohttp's frame parser on one connection and follows the frame
    boundaries of what the client sends (a header of at most 14 bytes, then the payload
    skipped by its length, so the cost is per frame, not per byte). A frame without the mask
    bit is a protocol error the server must close the connection for: the parser is fed
    nothing more, ``refuse`` gets the error (the reader sees it and closes with 1002)."""

    def __init__(self, parser: Any, refuse: Callable[[BaseException], None]) -> None:
        self.parser = parser
        self.refuse = refuse
        self._head = bytearray()
        self._skip = 0
        self._refused = False

    def feed_data(self, data: bytes) -> tuple[bool, bytes]:
        if self._refused:
            return REFUSED
        end = len(data)
        if not self._skip and not self._head and end >= 4:  # the common case first: one
            length = data[1] & 0x7F                         # whole frame, nothing to walk
            one_frame = end == 2 + (4 if data[1] & 0x80 else 0) + length if length < 126 \
                else length == 126 and end == 4 + (4 if data[1] & 0x80 else 0) + (
                    data[2] << 8 | data[3])
            if one_frame and data[1] & 0x80:
                result: tuple[bool, bytes] = self.parser.feed_data(data)
                return result
        if not self._check(data):
            self._refused = True
            self.refuse(WebSocketError(WSCloseCode.PROTOCOL_ERROR,
                                       "a frame from the client was not masked"))
            return REFUSED
        result = self.parser.feed_data(data)
        return result

    def feed_eof(self) -> None:
        self.parser.feed_eof()

    def _check(self, data: bytes) -> bool:
        """Walk the frame headers in ``data``; False at one without the mask bit."""
        end = len(data)
        pos = 0
        while pos < end:
            if self._skip:
                step = min(self._skip, end - pos)
                self._skip -= step
                pos += step
                continue
            need = _header_size(self._head)
            take = min(need - len(self._head), end - pos)
            self._head += data[pos:pos + take]
            pos += take
            if len(self._head) < _header_size(self._head):
                continue  # the header's length bytes told us it is longer; or more to come
            head = self._head
            if not head[1] & 0x80:
                return False
            length = head[1] & 0x7F
            if length == 126:
                length = int.from_bytes(head[2:4], "big")
            elif length == 127:
                length = int.from_bytes(head[2:10], "big")
            self._skip = length
            self._head = bytearray()
        return True


def _header_size(head: bytearray) -> int:
    """Bytes of a frame header whose first ``len(head)`` bytes are known (at least 2)."""
    if len(head) < 2:
        return 2
    length = head[1] & 0x7F
    extended = 2 if length == 126 else 8 if length == 127 else 0
    return 2 + extended + (4 if head[1] & 0x80 else 0)
