# ROS 2 message types: name normalisation, .msg parsing, strict JSON checking, gendeps text.
from __future__ import annotations

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
STRINGS = {"string", "wstring"}
TIME_TYPES = {"builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration"}
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


def check_message(name: str, value: Any, path: str = "msg") -> dict[str, Any]:
    """``value`` (decoded JSON) checked field by field against ``name``; missing fields take
    their defaults. Returns the normalised message (``{sec, nanosec}`` times, bytes for
    ``uint8[]``); raises :class:`MessageError` naming the first bad field."""
    if name in TIME_TYPES:
        return _check_time(name, value, path)
    if not isinstance(value, dict):
        raise MessageError(f"{path}: expected an object ({name}), got {_kind(value)}")
    spec = get_type(name)
    if not spec.names.issuperset(value):
        key = next(k for k in value if k not in spec.names)
        raise MessageError(f"{path}: message type {name} does not have a field {key!r}")
    out: dict[str, Any] = {}
    for f in spec.fields:
        if f.name not in value:
            out[f.name] = _now_stamp() if _is_header_stamp(name, f) else default_field(f)
            continue
        item = value[f.name]
        # the common cases without a call (and without the field's path, made only for errors)
        if not f.is_array and ((type(item) is float and f.base == "float64")
                               or (type(item) is str and f.base in STRINGS)):
            out[f.name] = item
        else:
            out[f.name] = _check_field(f, item, f"{path}.{f.name}")
    return out


def _is_header_stamp(owner: str, f: Field) -> bool:
    return owner == "std_msgs/msg/Header" and f.name == "stamp"


def _check_field(f: Field, value: Any, path: str) -> Any:
    if not f.is_array:
        return check_scalar(f.base, value, path)
    if f.base in BYTE_ARRAY_BASES:
        return _check_bytes(f, value, path)
    if not isinstance(value, list):
        raise MessageError(f"{path}: expected an array of {f.base}, got {_kind(value)}")
    if f.length is not None and len(value) != f.length:
        raise MessageError(f"{path}: expected exactly {f.length} items, got {len(value)}")
    if f.base in FLOAT_MAX:
        return [math.nan if v is None else check_scalar(f.base, v, f"{path}[{i}]")
                for i, v in enumerate(value)]
    return [check_scalar(f.base, v, f"{path}[{i}]") for i, v in enumerate(value)]


def _check_bytes(f: Field, value: Any, path: str) -> bytes:
    if isinstance(value, str):
        try:
            data = base64.b64decode(value, validate=True)
        except (binascii.Error, ValueError):
            raise MessageError(f"{path}: not valid base64") from None
    elif isinstance(value, list):
        data = bytes(check_scalar("uint8", v, f"{path}[{i}]") for i, v in enumerate(value))
    else:
        raise MessageError(f"{path}: expected base64 text or an array of uint8, got "
                           f"{_kind(value)}")
    if f.length is not None and len(data) != f.length:
        raise MessageError(f"{path}: expected exactly {f.length} bytes, got {len(data)}")
    return data


def check_scalar(base: str, value: Any, path: str) -> Any:
    if base in INT_RANGES:
        return _check_int(base, value, path)
    if base in FLOAT_MAX:
        return _check_float(base, value, path)
    if base == "bool":
        if not isinstance(value, bool):
            raise MessageError(f"{path}: expected bool, got {_kind(value)}")
        return value
    if base in ("string", "wstring"):
        if not isinstance(value, str):
            raise MessageError(f"{path}: expected string, got {_kind(value)}")
        return value
    return check_message(base, value, path)


def _check_int(base: str, value: Any, path: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise MessageError(f"{path}: expected {base}, got {_kind(value)}")
    low, high = INT_RANGES[base]
    if not low <= value <= high:
        raise MessageError(f"{path}: {value} is out of range for {base} ({low}..{high})")
    return value


def _check_float(base: str, value: Any, path: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MessageError(f"{path}: expected {base}, got {_kind(value)}")
    number = float(value)
    if math.isfinite(number) and abs(number) > FLOAT_MAX[base]:
        raise MessageError(f"{path}: {value} is out of range for {base}")
    return number


def _check_time(name: str, value: Any, path: str) -> dict[str, int]:
    if value == "now" and name.endswith("/Time"):
        return _now_stamp()
    if not isinstance(value, dict):
        raise MessageError(f"{path}: expected {{sec, nanosec}} ({name}), got {_kind(value)}")
    keys = set(value)
    if keys <= {"sec", "nanosec"}:
        sec_key, ns_key = "sec", "nanosec"
    elif keys <= {"secs", "nsecs"}:
        sec_key, ns_key = "secs", "nsecs"
    else:
        raise MessageError(f"{path}: expected {{sec, nanosec}} or {{secs, nsecs}}, got fields "
                           f"{sorted(keys)}")
    sec = _check_int("int32", value.get(sec_key, 0), f"{path}.{sec_key}")
    nanosec = _check_int("uint32", value.get(ns_key, 0), f"{path}.{ns_key}")
    return {"sec": sec, "nanosec": nanosec}


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
