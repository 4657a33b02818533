# rosbridge v2 wire codec (pure, no I/O): frames, field checks, encoding, fragments, status.
from __future__ import annotations

import base64
import json
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import orjson

STATUS_LEVELS = ("info", "warning", "error", "none")
#: longest topic or service name accepted, checked before anything else looks at the name
MAX_NAME_CHARS = 256
_ROS_NAME = re.compile(r"^(/[A-Za-z0-9_~]+)+$")

Id = str | int | None


class ProtocolError(Exception):
    """A request the server refuses. The session that handles the request answers it with a
    ``status`` error carrying the request's ``id``; raisers never pass the id themselves."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


def request_id(frame: Any) -> Id:
    """The ``id`` of a request when it is a string or integer (else ``None``)."""
    if isinstance(frame, dict):
        value = frame.get("id")
        if isinstance(value, str) or (isinstance(value, int) and not isinstance(value, bool)):
            return value
    return None


def parse_json(text: str | bytes) -> Any:
    """One WebSocket frame's JSON value, or ProtocolError."""
    try:
        return orjson.loads(text)  # refuses NaN, Infinity and overflowing numbers
    except orjson.JSONDecodeError as exc:
        raise ProtocolError(f"invalid JSON: {exc}") from None


def check_frame(value: Any) -> dict[str, Any]:
    """A parsed frame -> a request object with a string ``op``, or ProtocolError."""
    if not isinstance(value, dict):
        raise ProtocolError(f"a request must be a JSON object, got {type(value).__name__}")
    if "id" in value and request_id(value) is None and value["id"] is not None:
        raise ProtocolError("field 'id': expected a string or integer")
    if "op" not in value:
        raise ProtocolError("missing field 'op'")
    if not isinstance(value["op"], str):
        raise ProtocolError("field 'op': expected a string")
    return value


def decode_frame(text: str | bytes) -> dict[str, Any]:
    """One WebSocket frame -> a request object with a string ``op``, or ProtocolError."""
    return check_frame(parse_json(text))


# -- field access -------------------------------------------------------------------------------


def get_str(frame: dict[str, Any], key: str, default: str | None = None) -> str:
    value = frame.get(key, default)
    if not isinstance(value, str) or not value:
        what = "missing field" if key not in frame else "expected a non-empty string in field"
        raise ProtocolError(f"{frame['op']}: {what} {key!r}")
    return value


def get_number(frame: dict[str, Any], key: str, default: float, minval: float = 0.0) -> float:
    value = frame.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ProtocolError(f"{frame['op']}: field {key!r}: expected a number")
    if value < minval:
        raise ProtocolError(f"{frame['op']}: field {key!r}: must be >= {minval:g}")
    return float(value)


def get_int(frame: dict[str, Any], key: str, default: int | None) -> int | None:
    value = frame.get(key, default)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ProtocolError(f"{frame['op']}: field {key!r}: expected a non-negative integer")
    return value


def get_bool(frame: dict[str, Any], key: str, default: bool) -> bool:
    value = frame.get(key, default)
    if not isinstance(value, bool):
        raise ProtocolError(f"{frame['op']}: field {key!r}: expected true or false")
    return value


#: spelling -> canonical name, of names already found valid (bounded: cleared when full)
_VALID_NAMES: dict[str, str] = {}
VALID_NAMES_KEPT = 1024


def topic_name(frame: dict[str, Any], key: str = "topic") -> tuple[str, str]:
    """(canonical ``/name``, spelling as sent) of a topic or service field; its length is
    checked first (at most MAX_NAME_CHARS), so a huge name costs nothing. A name seen
    before is not checked again (a client publishes to the same topics over and over)."""
    sent = frame.get(key)
    if type(sent) is str:
        name = _VALID_NAMES.get(sent)
        if name is not None:
            return name, sent
    sent = get_str(frame, key)
    if len(sent) > MAX_NAME_CHARS:
        raise ProtocolError(f"{frame['op']}: {key} name {shown(sent)} is too long: the limit "
                            f"is {MAX_NAME_CHARS} characters")
    name = sent if sent.startswith("/") else "/" + sent
    if _ROS_NAME.match(name) is None:
        raise ProtocolError(f"{frame['op']}: {key} {sent!r} is not a valid ROS name")
    if len(_VALID_NAMES) >= VALID_NAMES_KEPT:
        _VALID_NAMES.clear()
    _VALID_NAMES[sent] = name
    return name, sent


def shown(value: Any, limit: int = 40) -> str:
    """A client's value for an error message: its repr, cut to about ``limit`` characters
    (a 1 MiB name is not echoed back)."""
    if isinstance(value, str) and len(value) > limit:
        return f"{value[:limit]!r}... ({len(value)} characters)"
    if isinstance(value, dict | list):
        return f"a {type(value).__name__} of {len(value)} items"
    text = repr(value)
    return text if len(text) <= limit + 2 else text[:limit] + "..."


# -- encoding -----------------------------------------------------------------------------------


def clean(value: Any) -> Any:
    """JSON-ready copy: non-finite floats -> None, bytes -> base64, numpy -> lists."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [clean(v) for v in value]
    if isinstance(value, bytes | bytearray):
        return base64.b64encode(value).decode("ascii")
    if hasattr(value, "tolist"):
        return clean(value.tolist())
    return value


def encode(message: dict[str, Any]) -> str:
    """Compact JSON text of a reply; non-finite floats become null. Messages of plain JSON
    types and numpy arrays (the common case) skip the clean-up walk."""
    try:
        return orjson.dumps(message, option=orjson.OPT_SERIALIZE_NUMPY).decode()
    except TypeError:  # bytes (uint8[] -> base64) or other types only clean() knows
        return json.dumps(clean(message), separators=(",", ":"), allow_nan=False)


#: topic spelling -> the start of its publish frame (bounded: cleared when full)
_PUBLISH_HEADS: dict[str, str] = {}


def publish_frame(topic: str, msg_json: str) -> str:
    """``{"op":"publish","topic":T,"msg":...}`` around an already encoded message."""
    head = _PUBLISH_HEADS.get(topic)
    if head is None:
        if len(_PUBLISH_HEADS) >= VALID_NAMES_KEPT:
            _PUBLISH_HEADS.clear()
        head = _PUBLISH_HEADS[topic] = \
            '{"op":"publish","topic":' + orjson.dumps(topic).decode() + ',"msg":'
    return head + msg_json + "}"


def status_frame(level: str, message: str, rid: Id = None) -> str:
    body: dict[str, Any] = {"op": "status", "level": level, "msg": message}
    if rid is not None:
        body["id"] = rid
    return encode(body)


def level_allows(threshold: str, level: str) -> bool:
    """Whether a status of ``level`` passes a client's ``set_level`` threshold."""
    return STATUS_LEVELS.index(level) >= STATUS_LEVELS.index(threshold)


# -- fragments ----------------------------------------------------------------------------------

FRAGMENT_COST = 64  # bytes each incoming fragment is counted for beyond its data (empty ones too)


def fragment_count(text: str, size: int) -> int:
    return math.ceil(len(text) / size)


def fragments(text: str, size: int, fragment_id: str | int) -> Iterator[str]:
    """Split an encoded message into ``fragment`` ops of at most ``size`` characters of data;
    lazily, so a sender can yield to the event loop between pieces."""
    total = fragment_count(text, size)
    head = '{"op":"fragment","id":' + orjson.dumps(fragment_id).decode() + ',"data":'
    tail = f',"total":{total}}}'
    for num in range(total):
        piece = orjson.dumps(text[num * size:(num + 1) * size]).decode()
        yield f'{head}{piece},"num":{num}{tail}'


def over_limit(what: str, limit: float, key: str) -> ProtocolError:
    """The refusal for a budget: names the limit and the ``[rosbridge]`` key that sets it."""
    shown = f"{limit:g}" if isinstance(limit, float) else str(limit)
    return ProtocolError(f"{what}: the limit is {shown} ([rosbridge] {key})")


@dataclass
class _Partial:
    total: int
    started: float
    parts: dict[int, str] = field(default_factory=dict)
    size: int = 0  # bytes counted: UTF-8 of the data plus FRAGMENT_COST per fragment


@dataclass(frozen=True)
class FragmentLimits:
    """Bounds of one client's unfinished incoming fragments."""

    max_message_bytes: int = 1048576
    max_sets: int = 8
    max_bytes: int = 2 * 1048576  # all sets together
    max_fragments: int = 100_000
    timeout_s: float = 60.0


class Defragmenter:
    """Joins incoming ``fragment`` ops by ``id``; bounded in bytes (UTF-8, every fragment
    counted), sets, fragments per message and age."""

    def __init__(self, limits: FragmentLimits) -> None:
        self.limits = limits
        self.held_bytes = 0
        self._pending: dict[str | int, _Partial] = {}

    def add(self, frame: dict[str, Any], now: float) -> str | None:
        """Take one fragment; the joined text when it completes the message, else None."""
        rid, data, num, total = self._fields(frame)
        self._expire(now)
        partial = self._partial(rid, total, now)
        cost = len(data.encode("utf-8", "surrogatepass")) + FRAGMENT_COST
        old = partial.parts.get(num)
        delta = cost - (len(old.encode("utf-8", "surrogatepass")) + FRAGMENT_COST
                        if old is not None else 0)
        self._check_room(rid, partial, delta)
        partial.parts[num] = data
        partial.size += delta
        self.held_bytes += delta
        if len(partial.parts) < total:
            return None
        self._drop(rid)
        return "".join(partial.parts[i] for i in range(total))

    def _fields(self, frame: dict[str, Any]) -> tuple[str | int, str, int, int]:
        rid = request_id(frame)
        if rid is None:
            raise ProtocolError("fragment: missing field 'id' (string or integer)")
        data = frame.get("data")
        if not isinstance(data, str):
            raise ProtocolError("fragment: field 'data': expected a string")
        num, total = get_int(frame, "num", None), get_int(frame, "total", None)
        if num is None or total is None or total < 1 or num >= total:
            raise ProtocolError("fragment: fields 'num' and 'total' must be integers with "
                                "0 <= num < total")
        if total > self.limits.max_fragments:
            raise over_limit(f"fragment: message {shown(rid)} would have {total} fragments",
                             self.limits.max_fragments, "max_fragments_per_message")
        return rid, data, num, total

    def _check_room(self, rid: str | int, partial: _Partial, delta: int) -> None:
        if partial.size + delta > self.limits.max_message_bytes:
            self._drop(rid)
            raise over_limit(f"fragment: message {shown(rid)} is larger than allowed; dropped",
                             self.limits.max_message_bytes, "max_message_bytes")
        if self.held_bytes + delta > self.limits.max_bytes:
            self._drop(rid)
            raise over_limit(f"fragment: this client's unfinished fragments would exceed the "
                             f"bytes allowed; message {shown(rid)} dropped", self.limits.max_bytes,
                             "max_fragment_bytes_per_client")

    def _partial(self, rid: str | int, total: int, now: float) -> _Partial:
        partial = self._pending.get(rid)
        if partial is not None and partial.total != total:
            self._drop(rid)
            raise ProtocolError(f"fragment: 'total' changed from {partial.total} to {total} "
                                f"for id {shown(rid)}; dropped")
        if partial is None:
            if len(self._pending) >= self.limits.max_sets:
                raise over_limit("fragment: too many fragmented messages in flight",
                                 self.limits.max_sets, "max_fragment_sets_per_client")
            partial = self._pending[rid] = _Partial(total, now)
        return partial

    def _drop(self, rid: str | int) -> None:
        partial = self._pending.pop(rid, None)
        if partial is not None:
            self.held_bytes -= partial.size

    def _expire(self, now: float) -> None:
        for rid in [r for r, p in self._pending.items()
                    if now - p.started > self.limits.timeout_s]:
            self._drop(rid)

    @property
    def pending(self) -> int:
        return len(self._pending)
