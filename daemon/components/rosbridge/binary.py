# rosbridge's binary frames (pure): a CBOR publish around a message, and `cbor-raw`'s wrapper.
from __future__ import annotations

import math
import struct
from functools import lru_cache

import cbor2

#: subscription encodings that send binary WebSocket frames
BINARY_COMPRESSIONS = ("cbor", "cbor-raw")

_FRAME_HEAD = b"\xa3" + cbor2.dumps("op") + cbor2.dumps("publish") + cbor2.dumps("topic")
_MSG_KEY = cbor2.dumps("msg")


_RAW_KEYS = [cbor2.dumps(key) for key in ("secs", "nsecs", "bytes")]


def publish_frame(spelling: str, msg_cbor: bytes) -> bytes:
    """CBOR ``{"op": "publish", "topic": T, "msg": M}`` around an already encoded message."""
    return b"".join((_frame_head(spelling), msg_cbor))


@lru_cache(maxsize=1024)
def _frame_head(spelling: str) -> bytes:
    return _FRAME_HEAD + cbor2.dumps(spelling) + _MSG_KEY


def cbor_raw_msg(cdr_bytes: bytes, t: float) -> bytes:
    """The ``msg`` of a ``cbor-raw`` frame: ``{"secs", "nsecs", "bytes"}`` with the server clock
    ``t`` and the CDR bytes, written directly (the bytes are copied once)."""
    secs = math.floor(t)
    nsecs = min(round((t - secs) * 1e9), 999_999_999)
    secs_key, nsecs_key, bytes_key = _RAW_KEYS
    return b"".join((b"\xa3", secs_key, _head(0, secs), nsecs_key, _head(0, nsecs),
                     bytes_key, _head(2, len(cdr_bytes)), cdr_bytes))


def _head(major: int, value: int) -> bytes:
    """A CBOR item head: unsigned integer (major 0) or byte-string length (major 2)."""
    kind = major << 5
    if value < 24:
        return bytes((kind | value,))
    if value < 0x100:
        return bytes((kind | 24, value))
    if value < 0x10000:
        return struct.pack(">BH", kind | 25, value)
    if value < 0x100000000:
        return struct.pack(">BI", kind | 26, value)
    return struct.pack(">BQ", kind | 27, value)
