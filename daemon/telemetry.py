# The daemon's shared bus keys and the telemetry records that travel on them.
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

from daemon.bus import BusKey
from sensors.scan import LaserScan


@dataclass(slots=True)
class OdomSample:
    """Odometry at one instant, in the units and frames of nav_msgs/Odometry. Made at the
    odometry rate and not changed after (not frozen: that costs ~4x to make)."""

    stamp: float  # wall clock, s
    frame_id: str
    child_frame_id: str
    x: float
    y: float
    theta: float
    linear_x: float
    angular_z: float
    pose_covariance_diagonal: list[float] = field(default_factory=list)
    twist_covariance_diagonal: list[float] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {"stamp": self.stamp, "frame_id": self.frame_id,
                "child_frame_id": self.child_frame_id,
                "pose": {"x": self.x, "y": self.y, "theta": self.theta},
                "twist": {"linear_x": self.linear_x, "angular_z": self.angular_z}}


@dataclass(slots=True)
class LatencyReport:
    """One stamped command's timeline: client send, daemon receipt, driver write (wall ms).
    Made once per command and not changed after (not frozen: a frozen dataclass costs four
    times as much to make, on the command path)."""

    id: str | int | None
    t_sent: float | None
    t_recv: float
    t_exec: float
    exec_ms: float
    source: str

    def to_json(self) -> dict[str, Any]:
        return {"id": self.id, "t_sent": self.t_sent, "t_recv": self.t_recv,
                "t_exec": self.t_exec, "exec_ms": self.exec_ms, "source": self.source,
                "transit_ms": None if self.t_sent is None else self.t_recv - self.t_sent}


@dataclass(slots=True)
class CommandEvent:
    """A motion command as received (published on the bus as ``command``): who sent what, and
    whether the control loop applied it. Made once per command and not changed after."""

    stamp: float  # wall clock, s
    source: str
    kind: str  # cmd_vel | estop | estop_release
    linear_x: float = 0.0
    angular_z: float = 0.0
    id: str | int | None = None
    accepted: bool = True
    error: str = ""


@dataclass(frozen=True, slots=True)
class Transform:
    """One planar transform for /tf: where ``child`` is in ``parent`` at ``stamp`` (wall
    clock, s)."""

    stamp: float
    parent: str
    child: str
    x: float
    y: float
    theta: float

    @classmethod
    def of_odometry(cls, sample: OdomSample) -> Transform:
        return cls(sample.stamp, sample.frame_id, sample.child_frame_id, sample.x, sample.y,
                   sample.theta)


@dataclass(frozen=True, slots=True)
class PowerEvent:
    """The battery's charge level changed: ``level`` is ok, low, very_low or critical;
    ``percentage`` 0..1; ``reason`` says why, for logs and refusals."""

    stamp: float
    level: str
    percentage: float
    reason: str


# -- the keys every part of the daemon shares (a component's own state keys live with it) ------

#: odometry from the control tick, at ``[control] publish_rate``
ODOM: BusKey[OdomSample] = BusKey("odom")
#: every motion command as received, and e-stop changes
COMMAND: BusKey[CommandEvent] = BusKey("command")
#: one per stamped command, after the driver write
LATENCY_REPORT: BusKey[LatencyReport] = BusKey("latency_report")
#: transforms for /tf, each batch from one publisher (odom -> base_link, map -> odom)
TRANSFORMS: BusKey[tuple[Transform, ...]] = BusKey("transforms")
#: fixed transforms for /tf_static (the lidar's mount), latest batch per publisher
STATIC_TRANSFORMS: BusKey[tuple[Transform, ...]] = BusKey("static_transforms")
#: one whole lidar revolution (the lidar component, or the lockstep simulator)
SCAN: BusKey[LaserScan] = BusKey("scan")
#: ``/api/health``'s body, once a second
HEALTH: BusKey[dict[str, Any]] = BusKey("health")
#: ``/api/health``'s body with its time ``t``, only when a status or problem text changed
HEALTH_CHANGE: BusKey[dict[str, Any]] = BusKey("health_change")
#: ``/api/robot_info``'s body, once a second
ROBOT_INFO: BusKey[dict[str, Any]] = BusKey("robot_info")
#: the simulated robot's true pose (sim mode only)
ODOM_GROUND_TRUTH: BusKey[OdomSample] = BusKey("odom_ground_truth")
#: the battery's charge level, on every change (critical: stop, close files, power off)
POWER: BusKey[PowerEvent] = BusKey("power")
#: the daemon's log lines (INFO and up), on the event loop's thread
LOG_RECORD: BusKey[logging.LogRecord] = BusKey("log")

