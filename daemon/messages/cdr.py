# ROS 2 CDR (little-endian XCDR1) encoders, compiled once per type from the daemon's .msg texts.
from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from daemon.messages.msgtypes import Field, get_type

#: the 4-byte encapsulation header of little-endian plain CDR (rosbridge's cbor-raw, MCAP "cdr")
ENCAPSULATION = b"\x00\x01\x00\x00"
HEADER_SIZE = len(ENCAPSULATION)

# primitive => (struct code, numpy dtype); sizes are the alignments
PRIMITIVE_CODES: dict[str, tuple[str, str]] = {
    "bool": ("?", "?"), "byte": ("B", "u1"), "char": ("B", "u1"), "uint8": ("B", "u1"),
    "int8": ("b", "i1"), "int16": ("h", "<i2"), "uint16": ("H", "<u2"),
    "int32": ("i", "<i4"), "uint32": ("I", "<u4"), "int64": ("q", "<i8"),
    "uint64": ("Q", "<u8"), "float32": ("f", "<f4"), "float64": ("d", "<f8"),
}
BYTE_BASES = ("uint8", "char", "byte")
U32 = struct.Struct("<I")
_ZEROS = bytes(8)

Writer = Callable[[bytearray, Any], None]


class CdrError(ValueError):
    """A message that cannot be serialised as its type; the text names the field."""


def encode(type_name: str, msg: Any) -> bytes:
    """``msg`` (a dict shaped like the type, arrays as lists, numpy arrays or bytes) as CDR,
    encapsulation header included."""
    buf = bytearray(ENCAPSULATION)
    try:
        message_writer(type_name)(buf, msg)
    except (KeyError, TypeError, struct.error) as exc:
        raise CdrError(f"{type_name}: cannot serialise: {exc!r}") from None
    return bytes(buf)


def _align(buf: bytearray, size: int) -> None:
    pad = -(len(buf) - HEADER_SIZE) % size
    if pad:
        buf += _ZEROS[:pad]


# -- compiling a type ---------------------------------------------------------------------------


@dataclass(frozen=True)
class _Leaf:
    """A fixed-size primitive inside a run: where its value is and how many there are."""

    path: tuple[str, ...]
    code: str
    count: int | None  # None: a scalar; else a fixed array of this many


@cache
def message_writer(type_name: str) -> Writer:
    """The compiled CDR writer of ``type_name``: runs of fixed-size primitives (also across
    nested messages) become one precompiled ``struct`` pack; the rest are field writers."""
    steps: list[Writer] = []
    run: list[_Leaf] = []
    for leaf_or_writer in _flatten(type_name, ()):
        if isinstance(leaf_or_writer, _Leaf):
            if run and _alignment(leaf_or_writer) > _alignment(run[0]):
                steps.append(_run_writer(run))
                run = []
            run.append(leaf_or_writer)
        else:
            if run:
                steps.append(_run_writer(run))
                run = []
            steps.append(leaf_or_writer)
    if run:
        steps.append(_run_writer(run))
    if not steps:  # ROS 2 writes an empty struct as one dummy byte
        steps.append(_EMPTY_STRUCT)

    def write(buf: bytearray, msg: Any) -> None:
        for step in steps:
            step(buf, msg)

    return write


def _EMPTY_STRUCT(buf: bytearray, msg: Any) -> None:
    buf.append(0)


def _flatten(type_name: str, prefix: tuple[str, ...]) -> list[_Leaf | Writer]:
    out: list[_Leaf | Writer] = []
    for f in get_type(type_name).fields:
        path = (*prefix, f.name)
        if f.base in PRIMITIVE_CODES and (not f.is_array or (
                f.length is not None and f.base not in BYTE_BASES)):
            out.append(_Leaf(path, PRIMITIVE_CODES[f.base][0], f.length if f.is_array else None))
        elif not f.is_primitive and not f.is_array:
            out.extend(_flatten(f.base, path))
        else:
            out.append(_at(path, _field_writer(f)))
    return out


def _alignment(leaf: _Leaf) -> int:
    return struct.calcsize(leaf.code)


def _get(msg: Any, path: tuple[str, ...]) -> Any:
    for key in path:
        msg = msg[key]
    return msg


def _at(path: tuple[str, ...], writer: Writer) -> Writer:
    """A writer of the value at ``path`` inside the message being written."""
    if len(path) == 1:
        key = path[0]
        return lambda buf, msg: writer(buf, msg[key])
    return lambda buf, msg: writer(buf, _get(msg, path))


def _run_writer(run: list[_Leaf]) -> Writer:
    """One ``struct`` for the run; the first leaf has the largest alignment, so the padding
    inside the run is the same wherever the run starts."""
    first = _alignment(run[0])
    fmt, offset = "<", 0
    for leaf in run:
        size = _alignment(leaf)
        pad = -offset % size
        fmt += "x" * pad + (f"{leaf.count}{leaf.code}" if leaf.count is not None else leaf.code)
        offset += pad + size * (leaf.count or 1)
    packer = struct.Struct(fmt)
    getters = [(leaf.path, leaf.count) for leaf in run]

    def write(buf: bytearray, msg: Any) -> None:
        values: list[Any] = []
        for path, count in getters:
            value = _get(msg, path)
            if count is None:
                values.append(value)
            else:
                values.extend(_fixed(value, count, path))
        _align(buf, first)
        buf += packer.pack(*values)

    return write


def _fixed(value: Any, count: int, path: tuple[str, ...]) -> Any:
    if len(value) != count:
        raise CdrError(f"{'.'.join(path)}: expected exactly {count} items, got {len(value)}")
    return value.tolist() if isinstance(value, np.ndarray) else value


# -- field writers (strings, sequences, byte arrays) ---------------------------------------------


def write_string(buf: bytearray, value: str) -> None:
    data = value.encode()
    _align(buf, 4)
    buf += U32.pack(len(data) + 1)
    buf += data
    buf.append(0)


def _field_writer(f: Field) -> Writer:
    if not f.is_array:
        if f.base == "string":
            return write_string
        raise CdrError(f"field {f.name}: type {f.base} is not supported")
    if f.base in BYTE_BASES:
        return _byte_array_writer(f.length)
    if f.base in PRIMITIVE_CODES:
        return _sequence_writer(PRIMITIVE_CODES[f.base][1])
    if f.base == "wstring":
        raise CdrError(f"field {f.name}: type wstring is not supported")
    element = write_string if f.base == "string" else message_writer(f.base)
    return _object_sequence_writer(element, f.length)


def _byte_array_writer(length: int | None) -> Writer:
    def write(buf: bytearray, value: Any) -> None:
        data = value if isinstance(value, bytes | bytearray) else bytes(value)
        if length is None:
            _align(buf, 4)
            buf += U32.pack(len(data))
        elif len(data) != length:
            raise CdrError(f"expected exactly {length} bytes, got {len(data)}")
        buf += data

    return write


def _sequence_writer(dtype: str) -> Writer:
    """An unbounded numeric sequence: count, then the elements as one numpy buffer."""
    size = np.dtype(dtype).itemsize

    def write(buf: bytearray, value: Any) -> None:
        array = as_array(value, dtype)
        _align(buf, 4)
        buf += U32.pack(len(array))
        if len(array):
            _align(buf, size)
            buf += array.tobytes()

    return write


def as_array(value: Any, dtype: str) -> np.ndarray:
    """A numeric sequence as a little-endian array; JSON ``null`` (a non-finite float that went
    through the JSON path) becomes NaN."""
    if isinstance(value, np.ndarray):
        return value.astype(dtype, copy=False).ravel()
    if value and any(v is None for v in value):
        value = [np.nan if v is None else v for v in value]
    return np.asarray(value, dtype=dtype).ravel()


def _object_sequence_writer(element: Writer, length: int | None) -> Writer:
    def write(buf: bytearray, value: Any) -> None:
        if length is None:
            _align(buf, 4)
            buf += U32.pack(len(value))
        elif len(value) != length:
            raise CdrError(f"expected exactly {length} items, got {len(value)}")
        for item in value:
            element(buf, item)

    return write
