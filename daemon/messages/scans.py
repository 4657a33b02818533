# LaserScan straight from its arrays: the float32 message and its CDR bytes (no per-ray loop).
from __future__ import annotations

import math
import operator
import struct
from collections.abc import Callable
from typing import Any

import numpy as np

from daemon.messages import cdr
from daemon.messages.convert import ScanLike, header


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
