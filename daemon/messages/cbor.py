# CBOR values of ROS 2 messages as rosbridge_suite sends them (uint8[] as bytes, typed arrays).
from __future__ import annotations

from collections.abc import Callable
from functools import cache
from typing import Any

import cbor2
import numpy as np

from daemon.messages import cdr
from daemon.messages.msgtypes import Field, get_type

# RFC 8746 little-endian typed-array tags, as rosbridge_suite sends them
TYPED_ARRAY_TAGS: dict[str, tuple[int, str]] = {
    "uint16": (69, "<u2"), "uint32": (70, "<u4"), "uint64": (71, "<u8"),
    "int8": (72, "i1"), "int16": (77, "<i2"), "int32": (78, "<i4"), "int64": (79, "<i8"),
    "float32": (85, "<f4"), "float64": (86, "<f8"),
}

Convert = Callable[[Any], Any]


def cbor_msg(type_name: str, msg: Any) -> bytes:
    """The ``msg`` of a ``cbor`` frame: the message as CBOR values of its type."""
    return cbor2.dumps(cbor_values(type_name, msg))


def cbor_values(type_name: str, msg: Any) -> Any:
    """``msg`` with uint8[] as bytes, variable-length numeric arrays as typed-array tags and
    fixed-size arrays as lists (times stay ``{sec, nanosec}``)."""
    convert = value_converter(type_name)
    return convert(msg) if convert is not None else msg


@cache
def value_converter(type_name: str) -> Convert | None:
    """The CBOR value conversion of a type; None when the message can be sent as it is."""
    steps = [(f.name, conv) for f in get_type(type_name).fields
             if (conv := _field_converter(f)) is not None]
    if not steps:
        return None

    def convert(msg: Any) -> Any:
        out = dict(msg)
        for name, conv in steps:
            out[name] = conv(msg[name])
        return out

    return convert


def _field_converter(f: Field) -> Convert | None:
    if not f.is_array:
        return None if f.is_primitive else value_converter(f.base)
    if f.base in cdr.BYTE_BASES:
        return _to_bytes
    if f.base in TYPED_ARRAY_TAGS and f.length is None:
        tag, dtype = TYPED_ARRAY_TAGS[f.base]
        return lambda value: cbor2.CBORTag(tag, cdr.as_array(value, dtype).tobytes())
    if f.is_primitive:
        return _to_list
    element = value_converter(f.base)
    if element is None:
        return _to_list
    return lambda value: [element(item) for item in value]


def _to_bytes(value: Any) -> bytes:
    if type(value) is bytes:
        return value
    if isinstance(value, bytes):  # a Blob: plain bytes for the CBOR encoder
        return bytes(value)
    if isinstance(value, np.ndarray):
        return value.astype("u1", copy=False).tobytes()
    return bytes(value)


def _to_list(value: Any) -> list[Any]:
    return value.tolist() if isinstance(value, np.ndarray) else list(value)
