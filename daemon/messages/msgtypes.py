# ROS 2 message types: name normalisation, .msg parsing, strict JSON checking, gendeps text.
from __future__ import annotations

import array
import base64
import binascii
import math
import re
import time
from dataclasses import dataclass
from functools import cache, cached_property
from typing import Any

from daemon.messages.definitions import MSG_TEXT

INT_RANGES: dict[str, tuple[int, int]] = {
    "int8": (-(2**7), 2**7 - 1), "uint8": (0, 2**8 - 1), "byte": (0, 255), "char": (0, 255),
    "int16": (-(2**15), 2**15 - 1), "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1), "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1), "uint64": (0, 2**64 - 1),
}
FLOAT_MAX = {"float32": 3.4028234663852886e38, "float64": math.inf}
PRIMITIVES = {"bool", "string", "wstring", "float32", "float64", *INT_RANGES}
BYTE_ARRAY_BASES = {"uint8", "char"}
TIME_TYPES = {"builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration"}
#: longest type name accepted (checked before the pattern looks at it)
MAX_TYPE_CHARS = 256
_NAME_PART = r"[A-Za-z][A-Za-z0-9_]*"
_TYPE_NAME = re.compile(rf"^({_NAME_PART})/(?:(msg|srv|action)/)?({_NAME_PART})$")
_FIELD_LINE = re.compile(r"^([A-Za-z0-9_/]+)(\[(\d*)\])?\s+([A-Za-z][A-Za-z0-9_]*)(?:\s+(.+))?$")
_CONST_LINE = re.compile(r"^([A-Za-z0-9_/]+)\s+([A-Z][A-Z0-9_]*)\s*=\s*(.+)$")


class MessageError(ValueError):
    """A message that does not fit its type; the text names the field path."""


@dataclass(frozen=True)
class Field:
    """One field of a message: ``base`` is a primitive or a full ``pkg/msg/Type`` name."""

    name: str
    base: str
    is_array: bool = False
    length: int | None = None  # fixed array length; None = unbounded
    default: Any = None

    @property
    def is_primitive(self) -> bool:
        return self.base in PRIMITIVES

    @property
    def declared(self) -> str:
        """The field type as ROS writes it in a type list (``float64[36]``)."""
        suffix = "" if not self.is_array else f"[{self.length if self.length else ''}]"
        return f"{self.base}{suffix}"


@dataclass(frozen=True)
class MsgType:
    name: str
    fields: tuple[Field, ...]
    constants: tuple[tuple[str, str, str], ...]
    text: str

    def field(self, name: str) -> Field | None:
        return next((f for f in self.fields if f.name == name), None)

    @cached_property
    def names(self) -> frozenset[str]:
        """The field names (checked against every incoming message's keys)."""
        return frozenset(f.name for f in self.fields)


def normalize_type(name: Any, kind: str = "msg") -> str:
    """``pkg/Type`` or ``pkg/msg/Type`` -> ``pkg/msg/Type``; a bad string is a MessageError."""
    if not isinstance(name, str):
        raise MessageError(f"type: expected a string like 'pkg/msg/Type', got "
                           f"{type(name).__name__}")
    if len(name) > MAX_TYPE_CHARS:
        raise MessageError(f"type {name[:40]!r}... ({len(name)} characters) is too long: the "
                           f"limit is {MAX_TYPE_CHARS} characters")
    match = _TYPE_NAME.match(name)
    if match is None:
        raise MessageError(f"type {name!r}: not a type name; expected 'pkg/Type' or "
                           f"'pkg/{kind}/Type'")
    package, middle, short = match.groups()
    if middle is not None and middle != kind:
        raise MessageError(f"type {name!r}: expected a {kind} type, not {middle}")
    return f"{package}/{kind}/{short}"


def short_name(full: str) -> str:
    """``pkg/msg/Type`` -> ``pkg/Type`` (the spelling of ``MSG:`` sections)."""
    package, _, short = full.split("/")
    return f"{package}/{short}"


def known_types() -> list[str]:
    return sorted(MSG_TEXT)


def has_type(name: str) -> bool:
    return name in MSG_TEXT


@cache
def get_type(name: str) -> MsgType:
    """The parsed definition of a full ``pkg/msg/Type`` name (KeyError when unknown)."""
    text = MSG_TEXT[name]
    package = name.split("/")[0]
    fields, constants = [], []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        const = _CONST_LINE.match(line)
        if const:
            constants.append((const.group(1), const.group(2), const.group(3).strip()))
            continue
        fields.append(_parse_field(line, package, name))
    return MsgType(name, tuple(fields), tuple(constants), text)


def _parse_field(line: str, package: str, owner: str) -> Field:
    match = _FIELD_LINE.match(line)
    if match is None:
        raise ValueError(f"{owner}: cannot parse field line {line!r}")
    base, array, length, fname, default = match.groups()
    if base not in PRIMITIVES:
        base = normalize_type(base if "/" in base else f"{package}/{base}")
    value = _parse_default(base, default) if default is not None else None
    return Field(fname, base, array is not None, int(length) if length else None, value)


def _parse_default(base: str, text: str) -> Any:
    if base in INT_RANGES:
        return int(text)
    if base in FLOAT_MAX:
        return float(text)
    if base == "bool":
        return text.lower() in ("true", "1")
    return text.strip("'\"")


# -- defaults -----------------------------------------------------------------------------


def default_message(name: str) -> dict[str, Any]:
    """A message of type ``name`` with every field at its default."""
    return {f.name: default_field(f) for f in get_type(name).fields}


def default_field(f: Field) -> Any:
    if f.is_array:
        if f.base in BYTE_ARRAY_BASES:
            return bytes(f.length or 0)
        return [default_scalar(f.base) for _ in range(f.length or 0)]
    if f.default is not None:
        return f.default
    return default_scalar(f.base)


def default_scalar(base: str) -> Any:
    if base in INT_RANGES:
        return 0
    if base in FLOAT_MAX:
        return 0.0
    if base == "bool":
        return False
    if base in ("string", "wstring"):
        return ""
    return default_message(base)


# -- checking JSON input --------------------------------------------------------------------
# Work is proportional to the message, with a small constant: uniform arrays (all int, all
# float, ...) are checked by C-level passes, nothing is copied that need not be, and the path
# naming a bad field is built only for the error (as it propagates up), never per element.


class _Bad(Exception):
    """A misfit below a message: what is wrong, and the path to it, innermost first."""

    def __init__(self, what: str) -> None:
        super().__init__(what)
        self.what = what
        self.where: list[str] = []

    def at(self, step: str) -> _Bad:
        self.where.append(step)
        return self

    def error(self, path: str) -> MessageError:
        return MessageError(f"{path}{''.join(reversed(self.where))}: {self.what}")


def check_message(name: str, value: Any, path: str = "msg") -> dict[str, Any]:
    """``value`` (decoded JSON) checked field by field against ``name``; missing fields take
    their defaults. Returns the normalised message (``{sec, nanosec}`` times, bytes for
    ``uint8[]``); raises :class:`MessageError` naming the first bad field."""
    try:
        return _message(name, value)
    except _Bad as bad:
        raise bad.error(path) from None


def check_scalar(base: str, value: Any, path: str) -> Any:
    """One value of a primitive or message type, checked (MessageError naming ``path``)."""
    try:
        return _scalar(base, value)
    except _Bad as bad:
        raise bad.error(path) from None


@cache
@cache
def _field_names(name: str) -> frozenset[str]:
    return frozenset(f.name for f in get_type(name).fields)


def _message(name: str, value: Any) -> dict[str, Any]:
    if name in TIME_TYPES:
        return _time(name, value)
    if not isinstance(value, dict):
        raise _Bad(f"expected an object ({name}), got {_kind(value)}")
    names = _field_names(name)
    for key in value:
        if key not in names:
            raise _Bad(f"message type {name} does not have a field {_short(key)}")
    out: dict[str, Any] = {}
    for f in get_type(name).fields:
        if f.name not in value:
            out[f.name] = _now_stamp() if _is_header_stamp(name, f) else default_field(f)
            continue
        try:
            out[f.name] = _field(f, value[f.name])
        except _Bad as bad:
            raise bad.at(f".{f.name}") from None
    return out


def _is_header_stamp(owner: str, f: Field) -> bool:
    return owner == "std_msgs/msg/Header" and f.name == "stamp"


def _field(f: Field, value: Any) -> Any:
    if not f.is_array:
        return _scalar(f.base, value)
    if f.base in BYTE_ARRAY_BASES:
        return _bytes(f, value)
    if not isinstance(value, list):
        raise _Bad(f"expected an array of {f.base}, got {_kind(value)}")
    if f.length is not None and len(value) != f.length:
        raise _Bad(f"expected exactly {f.length} items, got {len(value)}")
    uniform = _uniform(f.base, value)
    if uniform is not None:
        return uniform
    nullable = f.base in FLOAT_MAX  # null stands for NaN in float arrays
    try:
        return [math.nan if v is None and nullable else _scalar(f.base, v) for v in value]
    except _Bad:
        pass
    raise _first_bad(f.base, value, nullable)


def _first_bad(base: str, items: list[Any], nullable: bool = False) -> _Bad:
    """The misfit of the first bad item, named by its index (only on the error path)."""
    for index, item in enumerate(items):
        if item is None and nullable:
            continue
        try:
            _scalar(base, item)
        except _Bad as bad:
            return bad.at(f"[{index}]")
    return _Bad("an item does not fit")  # not reached: the caller found one


#: the array module's code for each integer type: its constructor range-checks in C
_INT_CODES = {"int8": "b", "uint8": "B", "byte": "B", "char": "B", "int16": "h", "uint16": "H",
              "int32": "i", "uint32": "I", "int64": "q", "uint64": "Q"}


def _uniform(base: str, items: list[Any]) -> list[Any] | None:
    """``items`` checked by C-level passes when all are of the one expected JSON type (the
    common case); None when the items must be checked one by one."""
    if not items:
        return []
    kinds = set(map(type, items))  # one pass; bool is its own type, so it is never let through
    if base in INT_RANGES:
        if kinds != {int}:
            return None
        try:
            array.array(_INT_CODES[base], items)  # the range check, in C
        except OverflowError:
            return None
        return items
    if base in FLOAT_MAX:
        if not kinds <= {float, int}:
            return None
        numbers = items if kinds == {float} else list(map(float, items))
        if base != "float64" and (max(numbers) > FLOAT_MAX[base]
                                  or min(numbers) < -FLOAT_MAX[base]):
            return None  # out of range or infinite: one by one says which
        return numbers
    if base in ("string", "wstring"):
        return items if kinds == {str} else None
    if base == "bool":
        return items if kinds == {bool} else None
    return None


def _bytes(f: Field, value: Any) -> bytes:
    if isinstance(value, str):
        try:
            data = base64.b64decode(value, validate=True)
        except (binascii.Error, ValueError):
            raise _Bad("not valid base64") from None
    elif isinstance(value, list):
        try:
            if value and set(map(type, value)) != {int}:  # bool is its own type: refused
                raise ValueError
            data = bytes(value)  # the range check, in C
        except ValueError:
            raise _first_bad("uint8", value) from None
    else:
        raise _Bad(f"expected base64 text or an array of uint8, got {_kind(value)}")
    if f.length is not None and len(data) != f.length:
        raise _Bad(f"expected exactly {f.length} bytes, got {len(data)}")
    return data


def _scalar(base: str, value: Any) -> Any:
    if base in INT_RANGES:
        return _int(base, value)
    if base in FLOAT_MAX:
        return _float(base, value)
    if base == "bool":
        if not isinstance(value, bool):
            raise _Bad(f"expected bool, got {_kind(value)}")
        return value
    if base in ("string", "wstring"):
        if not isinstance(value, str):
            raise _Bad(f"expected string, got {_kind(value)}")
        return value
    return _message(base, value)


def _int(base: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise _Bad(f"expected {base}, got {_kind(value)}")
    low, high = INT_RANGES[base]
    if not low <= value <= high:
        raise _Bad(f"{value} is out of range for {base} ({low}..{high})")
    return value


def _float(base: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _Bad(f"expected {base}, got {_kind(value)}")
    number = float(value)
    if math.isfinite(number) and abs(number) > FLOAT_MAX[base]:
        raise _Bad(f"{value} is out of range for {base}")
    return number


# The spellings of a time's two fields, each accepted alone or with either of the other:
# ROS 2 (sec, nanosec), ROS 1 (secs, nsecs) as rosbridge_suite reads them, and Foxglove's own
# Time (sec, nsec), which its app writes when it publishes. Output is always {sec, nanosec}.
TIME_SECONDS = ("sec", "secs")
TIME_NANOSECONDS = ("nanosec", "nsecs", "nsec")
TIME_SPELLINGS = "{sec, nanosec}, {secs, nsecs} or {sec, nsec}"


def _time(name: str, value: Any) -> dict[str, int]:
    if value == "now" and name.endswith("/Time"):
        return _now_stamp()
    if not isinstance(value, dict):
        raise _Bad(f"expected {TIME_SPELLINGS} ({name}), got {_kind(value)}")
    if not set(value) <= {*TIME_SECONDS, *TIME_NANOSECONDS}:
        raise _Bad(f"expected {TIME_SPELLINGS}, got fields "
                   f"{sorted(_short(k) for k in value)[:8]}")
    return {"sec": _time_part(value, TIME_SECONDS, "int32"),
            "nanosec": _time_part(value, TIME_NANOSECONDS, "uint32")}


def _time_part(value: dict[str, Any], spellings: tuple[str, ...], base: str) -> int:
    """One field of a time under whichever of its spellings is there (0 when none is)."""
    given = [key for key in spellings if key in value]
    if len(given) > 1:
        raise _Bad(f"{' and '.join(given)} are the same field; give one")
    if not given:
        return 0
    try:
        return _int(base, value[given[0]])
    except _Bad as bad:
        raise bad.at(f".{given[0]}") from None


def _short(key: str, limit: int = 40) -> str:
    """A client's key for an error message: its repr, cut short."""
    return repr(key) if len(key) <= limit else f"{key[:limit]!r}... ({len(key)} characters)"


def _now_stamp() -> dict[str, int]:
    return stamp(time.time())


def stamp(t: float) -> dict[str, int]:
    """Wall-clock seconds -> ``{sec, nanosec}``."""
    sec = math.floor(t)
    nanosec = min(round((t - sec) * 1e9), 999_999_999)
    return {"sec": int(sec), "nanosec": nanosec}


def _kind(value: Any) -> str:
    if value is None:
        return "null"
    text = repr(value)
    if len(text) > 40:
        text = text[:37] + "..."
    return f"{type(value).__name__} {text}"


# -- typedef text (gendeps --cat layout) -------------------------------------------------------


def dependencies(name: str) -> list[str]:
    """Every nested message type of ``name``, depth first, each once."""
    seen: list[str] = []

    def visit(type_name: str) -> None:
        for f in get_type(type_name).fields:
            if not f.is_primitive and f.base not in seen:
                seen.append(f.base)
                visit(f.base)

    visit(name)
    return seen


@cache
def full_text(name: str) -> str:
    """The root .msg text, then a ``MSG: pkg/Type`` section per nested type."""
    parts = [get_type(name).text.rstrip("\n")]
    for dep in dependencies(name):
        parts.append("=" * 80 + "\nMSG: " + short_name(dep) + "\n"
                     + get_type(dep).text.rstrip("\n"))
    return "\n".join(parts)
