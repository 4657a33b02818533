# The Foxglove WebSocket protocol's frames (pure): server ops out, client ops in, checked.
from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any

#: the subprotocols accepted, newest first (Foxglove's SDK; the older name Lichtblick and
#: Foxglove Studio offer)
SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")

# binary opcodes, server -> client and client -> server
MESSAGE_DATA = 1
TIME = 2
SERVICE_CALL_RESPONSE = 3
CLIENT_MESSAGE_DATA = 1
CLIENT_SERVICE_CALL_REQUEST = 2

# status levels
INFO, WARNING, ERROR = 0, 1, 2

U32_MAX = 0xFFFFFFFF
_MESSAGE_HEAD = struct.Struct("<BIQ")
_TIME = struct.Struct("<BQ")
_CHANNEL = struct.Struct("<I")

#: every op a client may send as text, with the one list field each carries (if any)
CLIENT_OPS = {
    "subscribe": "subscriptions", "unsubscribe": "subscriptionIds",
    "advertise": "channels", "unadvertise": "channelIds",
    "getParameters": "parameterNames", "setParameters": "parameters",
    "subscribeParameterUpdates": "parameterNames",
    "unsubscribeParameterUpdates": "parameterNames",
    "subscribeConnectionGraph": None, "unsubscribeConnectionGraph": None,
    "fetchAsset": None,
}
#: most entries one op's list may carry (a frame is small already; this bounds the work)
MAX_LIST = 1024


class ProtocolError(ValueError):
    """A client frame that does not follow the protocol; the text says what is wrong."""


@dataclass(frozen=True)
class ClientMessage:
    """A client's binary ``MESSAGE_DATA``: the channel it advertised and the payload."""

    channel_id: int
    payload: bytes


def message_data(subscription_id: int, t_ns: int, payload: bytes) -> bytes:
    return b"".join((_MESSAGE_HEAD.pack(MESSAGE_DATA, subscription_id, t_ns), payload))


def time_frame(t_ns: int) -> bytes:
    return _TIME.pack(TIME, t_ns)


def text(op: str, **fields: Any) -> str:
    return json.dumps({"op": op, **fields}, separators=(",", ":"), allow_nan=False)


def status(level: int, message: str, status_id: str | None = None) -> str:
    extra = {"id": status_id} if status_id is not None else {}
    return text("status", level=level, message=message, **extra)


def parse_binary(data: bytes) -> ClientMessage:
    """A client's binary frame; only ``MESSAGE_DATA`` is served (no services are advertised)."""
    if not data:
        raise ProtocolError("empty binary frame")
    if data[0] == CLIENT_SERVICE_CALL_REQUEST:
        raise ProtocolError("service calls are not offered by this server")
    if data[0] != CLIENT_MESSAGE_DATA:
        raise ProtocolError(f"unknown binary opcode 0x{data[0]:02x}")
    if len(data) < 5:
        raise ProtocolError("message data: shorter than its 5-byte header")
    return ClientMessage(_CHANNEL.unpack_from(data, 1)[0], bytes(data[5:]))


def parse_text(data: str) -> tuple[str, dict[str, Any]]:
    """A client's text frame: its op and the frame, the op's list field checked to be a list."""
    try:
        frame = json.loads(data)
    except (ValueError, RecursionError):
        raise ProtocolError("not JSON") from None
    if not isinstance(frame, dict):
        raise ProtocolError("a frame must be a JSON object")
    op = frame.get("op")
    if not isinstance(op, str) or op not in CLIENT_OPS:
        raise ProtocolError(f"unknown op {str(op)[:40]!r}")
    key = CLIENT_OPS[op]
    if key is not None:
        items = frame.get(key, [] if op.endswith("Parameters") else None)
        if not isinstance(items, list):
            raise ProtocolError(f"{op}: '{key}' must be a list")
        if len(items) > MAX_LIST:
            raise ProtocolError(f"{op}: '{key}' has {len(items)} entries (at most {MAX_LIST})")
    return op, frame


def uint32(value: Any, what: str) -> int:
    """An id field: an integer 0 .. 2^32-1 (never a bool, a float or a string)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= U32_MAX:
        raise ProtocolError(f"{what} must be an integer 0..{U32_MAX}, not {_short(value)}")
    return value


def string(value: Any, what: str, limit: int = 256) -> str:
    if not isinstance(value, str) or not value or len(value) > limit:
        raise ProtocolError(f"{what} must be a non-empty string of at most {limit} "
                            f"characters, not {_short(value)}")
    return value


def field(entry: Any, key: str, what: str) -> Any:
    if not isinstance(entry, dict):
        raise ProtocolError(f"{what}: each entry must be an object, not {_short(entry)}")
    if key not in entry:
        raise ProtocolError(f"{what}: missing field '{key}'")
    return entry[key]


def _short(value: Any) -> str:
    shown = json.dumps(value) if isinstance(value, (str, int, float, bool)) or value is None \
        else type(value).__name__
    return shown if len(shown) <= 40 else shown[:37] + "..."
