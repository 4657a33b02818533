# rosbridge's binary encodings (pure): `cbor` values, `cbor-raw` CDR frames, array-backed scans.
from __future__ import annotations

import math
import operator
import struct
from collections.abc import Callable
from functools import cache, lru_cache
from typing import Any

import cbor2
import numpy as np

from daemon.rosbridge import cdr
from daemon.rosbridge.msgtypes import Field, get_type
from daemon.rosbridge.topics import ScanLike, header

#: subscription encodings that send binary WebSocket frames
BINARY_COMPRESSIONS = ("cbor", "cbor-raw")

# RFC 8746 little-endian typed-array tags, as rosbridge_suite sends them
TYPED_ARRAY_TAGS: dict[str, tuple[int, str]] = {
    "uint16": (69, "<u2"), "uint32": (70, "<u4"), "uint64": (71, "<u8"),
    "int8": (72, "i1"), "int16": (77, "<i2"), "int32": (78, "<i4"), "int64": (79, "<i8"),
    "float32": (85, "<f4"), "float64": (86, "<f8"),
}

Convert = Callable[[Any], Any]

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
    if isinstance(value, bytes):
        return value
    if isinstance(value, np.ndarray):
        return value.astype("u1", copy=False).tobytes()
    return bytes(value)


def _to_list(value: Any) -> list[Any]:
    return value.tolist() if isinstance(value, np.ndarray) else list(value)


# -- robot topics whose binary form skips the JSON shaping ---------------------------------------


def scan_arrays(scan: ScanLike) -> dict[str, Any]:
    """A LaserScan message with its ranges and intensities as float32 arrays (no rounding,
    ``inf`` kept): what the CDR and CBOR encoders take without a per-ray Python loop."""
    return {
        "header": header(float(scan.stamp), getattr(scan, "frame_id", "laser")),
        **{key: float(getattr(scan, key)) for key in (
            "angle_min", "angle_max", "angle_increment", "time_increment", "scan_time",
            "range_min", "range_max")},
        "ranges": _float32(scan.ranges),
        "intensities": _float32(getattr(scan, "intensities", None)),
    }


def _float32(values: Any) -> np.ndarray:
    return np.asarray(values if values is not None else [], dtype=np.float32).ravel()


def scan_cdr(scan: ScanLike) -> bytes:
    """sensor_msgs/msg/LaserScan as CDR straight from the scan's arrays: after the string, every
    field is 4-aligned, so the layout is fixed and the arrays are copied once."""
    sec, nanosec = stamp_parts(float(scan.stamp))
    frame_id = getattr(scan, "frame_id", "laser").encode()
    ranges, intensities = _le32(scan.ranges), _le32(getattr(scan, "intensities", None))
    pad = -(len(frame_id) + 1) % 4
    return b"".join((
        cdr.ENCAPSULATION, _STAMP_LEN.pack(sec, nanosec, len(frame_id) + 1), frame_id,
        _NULS[:1 + pad], _SCAN_FIELDS.pack(*_scan_floats(scan), len(ranges)),
        ranges.tobytes(), cdr.U32.pack(len(intensities)), intensities.tobytes()))


def _le32(values: Any) -> np.ndarray:
    return np.asarray(values if values is not None else (), dtype="<f4").reshape(-1)


def stamp_parts(t: float) -> tuple[int, int]:
    sec = math.floor(t)
    return int(sec), min(round((t - sec) * 1e9), 999_999_999)


_STAMP_LEN = struct.Struct("<iII")
_SCAN_FLOATS = ("angle_min", "angle_max", "angle_increment", "time_increment", "scan_time",
                "range_min", "range_max")
_scan_floats = operator.attrgetter(*_SCAN_FLOATS)
_SCAN_FIELDS = struct.Struct("<7fI")
_NULS = bytes(4)

#: robot message types whose binary encodings start from their own conversion
BINARY_CONVERT: dict[str, Callable[[Any], dict[str, Any]]] = {
    "sensor_msgs/msg/LaserScan": scan_arrays,
}
#: robot message types with a CDR encoder of their own (the generic one is checked against it)
BINARY_CDR: dict[str, Callable[[Any], bytes]] = {
    "sensor_msgs/msg/LaserScan": scan_cdr,
}
