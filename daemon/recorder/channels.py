# What the flight recorder writes: one MCAP channel per topic, each a ROS 2 type and a conversion.
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from daemon.messages import cdr
from daemon.messages.convert import header, latency_msg, log_msg, odometry_msg, tf_msg
from daemon.messages.definitions import LASER_SCAN, LOG, ODOMETRY, STRING, TF_MESSAGE
from daemon.messages.msgtypes import stamp
from daemon.messages.scans import scan_arrays, scan_cdr
from daemon.telemetry import CommandEvent

COMMAND = "arbiterd_msgs/msg/Command"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
DIAGNOSTIC_LEVELS = {"ok": 0, "degraded": 1, "error": 2}


@dataclass(frozen=True)
class Channel:
    """One recorded topic: its ROS 2 type and how a bus message becomes that message."""

    topic: str
    type: str
    convert: Callable[[Any], dict[str, Any]]
    encode: Callable[[Any], bytes] | None = None  # a CDR encoder of its own (scans)

    def cdr(self, source: Any) -> bytes:
        if self.encode is not None:
            return self.encode(source)
        return cdr.encode(self.type, self.convert(source))


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
                                problem(component), component))
    return {"header": header(float(health.get("t", 0.0)), ""), "status": statuses}


def problem(component: dict[str, Any]) -> str:
    """The text that explains a component's status (empty when it is ok)."""
    for key in ("error", "fault", "message", "problem"):
        value = component.get(key)
        if value:
            return str(value)
    return ""


def _status(name: str, status: str, message: str, values: dict[str, Any]) -> dict[str, Any]:
    return {"level": DIAGNOSTIC_LEVELS.get(status, 2), "name": name,
            "message": message or status, "hardware_id": "",
            "values": [{"key": str(k), "value": str(v)} for k, v in values.items()
                       if not isinstance(v, dict | list)]}


def health_digest(health: dict[str, Any]) -> tuple[Any, ...]:
    """What counts as a health change: statuses and problem texts, not counters."""
    components = health.get("components", {})
    return (health.get("status"), health.get("state"),
            *((name, c.get("status"), problem(c)) for name, c in sorted(components.items())))


def bus_channels(*, sim: bool, odom_tf: bool) -> dict[str, list[Channel]]:
    """Bus topic => the channels its messages are recorded on."""
    odom = [Channel("/odom", ODOMETRY, odometry_msg)]
    if odom_tf:
        odom.append(Channel("/tf", TF_MESSAGE, tf_msg))
    channels = {
        "odom": odom,
        "scan": [Channel("/scan", LASER_SCAN, scan_arrays, scan_cdr)],
        "latency_report": [Channel("/latency_reports", STRING, latency_msg)],
        "command": [Channel("/commands", COMMAND, command_msg)],
        "health": [Channel("/diagnostics", DIAGNOSTIC_ARRAY, diagnostics_msg)],
    }
    if sim:
        channels["odom_ground_truth"] = [Channel("/odom_ground_truth", ODOMETRY, odometry_msg)]
    return channels


ROSOUT = Channel("/rosout", LOG, log_msg)


def log_record_source(record: logging.LogRecord) -> logging.LogRecord:
    """Format the message now, on the logging thread, so later changes to its arguments do not
    change what is recorded."""
    copy = logging.makeLogRecord(record.__dict__)
    copy.msg, copy.args = record.getMessage(), None
    return copy
