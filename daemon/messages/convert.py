# Daemon telemetry as ROS 2 messages (dicts of the message's fields), and the JSON fallback.
from __future__ import annotations

import base64
import logging
import math
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
import orjson

from daemon.health import problem_of
from daemon.messages.msgtypes import stamp
from daemon.telemetry import CommandEvent, LatencyReport, OdomSample, Transform


class ScanLike(Protocol):
    """What /scan needs from a lidar revolution (sensor_msgs/LaserScan field names)."""

    stamp: float
    frame_id: str
    angle_min: float
    angle_max: float
    angle_increment: float
    time_increment: float
    scan_time: float
    range_min: float
    range_max: float
    ranges: Any
    intensities: Any


class Blob(bytes):
    """uint8[] data (a JPEG) that JSON carries as base64, as rosbridge_suite does; CDR and
    CBOR carry the bytes as they are."""

    __slots__ = ()

    def to_json(self) -> str:
        return base64.b64encode(self).decode("ascii")


def header(t: float, frame_id: str) -> dict[str, Any]:
    return {"stamp": stamp(t), "frame_id": frame_id}


def quaternion_z(theta: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(theta / 2), "w": math.cos(theta / 2)}


def covariance(diagonal: list[float]) -> list[float]:
    matrix = [0.0] * 36
    for i, value in enumerate(diagonal[:6]):
        matrix[i * 7] = float(value)
    return matrix


def odometry_msg(sample: OdomSample) -> dict[str, Any]:
    zero = {"x": 0.0, "y": 0.0, "z": 0.0}
    return {
        "header": header(sample.stamp, sample.frame_id),
        "child_frame_id": sample.child_frame_id,
        "pose": {"pose": {"position": {"x": sample.x, "y": sample.y, "z": 0.0},
                          "orientation": quaternion_z(sample.theta)},
                 "covariance": covariance(sample.pose_covariance_diagonal)},
        "twist": {"twist": {"linear": {"x": sample.linear_x, "y": 0.0, "z": 0.0},
                            "angular": {**zero, "z": sample.angular_z}},
                  "covariance": covariance(sample.twist_covariance_diagonal)},
    }


def tf_msg(transforms: tuple[Transform, ...]) -> dict[str, Any]:
    return {"transforms": [{
        "header": header(t.stamp, t.parent),
        "child_frame_id": t.child,
        "transform": {"translation": {"x": t.x, "y": t.y, "z": 0.0},
                      "rotation": quaternion_z(t.theta)},
    } for t in transforms]}


RANGE_DECIMALS = 4  # 0.1 mm: finer than any RPLIDAR reports; halves the JSON work per scan


def float_list(values: Any, decimals: int | None = None) -> list[Any]:
    """A float sequence (numpy or list) as JSON-ready floats, non-finite -> None."""
    array = np.asarray(values if values is not None else [], dtype=np.float64).ravel()
    if decimals is not None:
        array = np.round(array, decimals)
    out: list[Any] = array.tolist()
    if not np.isfinite(array).all():
        for i in np.flatnonzero(~np.isfinite(array)).tolist():
            out[i] = None
    return out


def scan_msg(scan: ScanLike) -> dict[str, Any]:
    return {
        "header": header(float(scan.stamp), getattr(scan, "frame_id", "laser")),
        **{key: float(getattr(scan, key)) for key in (
            "angle_min", "angle_max", "angle_increment", "time_increment", "scan_time",
            "range_min", "range_max")},
        "ranges": float_list(scan.ranges, RANGE_DECIMALS),
        "intensities": float_list(getattr(scan, "intensities", None)),
    }


def scan_json_msg(scan: ScanLike) -> dict[str, Any]:
    """:func:`scan_msg` for a JSON encoder only: ranges and intensities stay float64 numpy
    arrays, which orjson writes straight from their buffers (non-finite as null): the same
    text, ~2.5x faster than lists of Python floats, and this runs on the event loop once per
    revolution while JSON clients subscribe to /scan."""
    return {
        "header": header(float(scan.stamp), getattr(scan, "frame_id", "laser")),
        **{key: float(getattr(scan, key)) for key in (
            "angle_min", "angle_max", "angle_increment", "time_increment", "scan_time",
            "range_min", "range_max")},
        "ranges": np.ascontiguousarray(np.round(_float64(scan.ranges), RANGE_DECIMALS)),
        "intensities": np.ascontiguousarray(_float64(getattr(scan, "intensities", None))),
    }


def _float64(values: Any) -> np.ndarray:
    return np.asarray(values if values is not None else [], dtype=np.float64).ravel()


#: conversions whose result only goes to a JSON encoder, by the topic's own conversion
JSON_CONVERT: dict[Callable[[Any], dict[str, Any]], Callable[[Any], dict[str, Any]]] = {
    scan_msg: scan_json_msg,
}


def json_string_msg(payload: Any) -> dict[str, Any]:
    """A std_msgs/String carrying ``payload`` as JSON (non-finite floats as null)."""
    data = orjson.dumps(payload, default=to_json, option=orjson.OPT_SERIALIZE_NUMPY)
    return {"data": data.decode()}


def latency_msg(report: LatencyReport) -> dict[str, Any]:
    return json_string_msg(report.to_json())


def latency_msg_json(report: LatencyReport) -> str:
    """``latency_msg``'s JSON text in one go (once per stamped command; the same text
    :func:`json_string_msg` and an orjson encoding of its result give)."""
    data = orjson.dumps(report.to_json(), default=to_json, option=orjson.OPT_SERIALIZE_NUMPY)
    return '{"data":' + orjson.dumps(data.decode()).decode() + "}"


#: conversions whose result only goes to a JSON encoder, straight to its text
JSON_TEXT: dict[Callable[[Any], dict[str, Any]], Callable[[Any], str]] = {
    latency_msg: latency_msg_json,
}


def to_json(value: Any) -> Any:
    """The JSON fallback of orjson and json: ``to_json()`` objects and numpy arrays."""
    if hasattr(value, "to_json"):
        return value.to_json()
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


LOG_LEVELS = ((logging.CRITICAL, 50), (logging.ERROR, 40), (logging.WARNING, 30),
              (logging.INFO, 20))


def log_msg(record: logging.LogRecord) -> dict[str, Any]:
    level = next((ros for py, ros in LOG_LEVELS if record.levelno >= py), 10)
    return {"stamp": stamp(record.created), "level": level, "name": record.name,
            "msg": record.getMessage(), "file": record.pathname, "function": record.funcName,
            "line": record.lineno}


DIAGNOSTIC_LEVELS = {"ok": 0, "degraded": 1, "error": 2}


def command_msg(event: CommandEvent) -> dict[str, Any]:
    zero = {"x": 0.0, "y": 0.0, "z": 0.0}
    return {"stamp": stamp(event.stamp), "source": event.source, "kind": event.kind,
            "id": "" if event.id is None else str(event.id),
            "twist": {"linear": {**zero, "x": event.linear_x},
                      "angular": {**zero, "z": event.angular_z}},
            "accepted": event.accepted, "error": event.error}


def diagnostics_msg(health: dict[str, Any]) -> dict[str, Any]:
    """``/api/health`` as a DiagnosticArray: the daemon, then one status per component."""
    statuses = [_status("arbiterd", health.get("status", "error"),
                        f"{health.get('state')}, {health.get('mode')} mode, driver "
                        f"{health.get('driver')}", {})]
    for name, component in sorted(health.get("components", {}).items()):
        statuses.append(_status(name, component.get("status", "error"),
                                problem_of(component), component))
    return {"header": header(float(health.get("t", 0.0)), ""), "status": statuses}


def _status(name: str, status: str, message: str, values: dict[str, Any]) -> dict[str, Any]:
    return {"level": DIAGNOSTIC_LEVELS.get(status, 2), "name": name,
            "message": message or status, "hardware_id": "",
            "values": [{"key": str(k), "value": str(v)} for k, v in values.items()
                       if not isinstance(v, dict | list)]}
