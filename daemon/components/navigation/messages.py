# Navigation's messages: goals from /goal_pose or JSON (checked), and the plan as nav_msgs/Path.
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from daemon import coords
from daemon.components.mapping.messages import yaw_of
from daemon.messages.convert import header, quaternion_z

#: built-in paths by name: (default size m, smallest, largest)
BUILTIN_PATHS = {"figure_eight": (2.0, 0.5, 20.0)}
#: the most waypoints one request may carry
MAX_WAYPOINTS = 1000


class GoalError(ValueError):
    """A goal that cannot be taken, with the reason for the client."""


@dataclass(frozen=True)
class GoalRequest:
    """A checked request: a pose (``waypoints`` and ``path`` empty), waypoints to follow, or
    a built-in path of ``size`` m started where the robot stands."""

    frame: str
    x: float = 0.0
    y: float = 0.0
    yaw: float | None = None
    waypoints: tuple[tuple[float, float], ...] = ()
    path: str = ""
    size: float = 0.0
    #: the goal's own tolerances (None: [navigation] xy_tolerance, yaw_tolerance)
    xy_tolerance: float | None = None
    yaw_tolerance: float | None = None


@dataclass(frozen=True, slots=True)
class PlanMessage:
    stamp: float
    frame_id: str
    points: np.ndarray


def goal_of_pose_stamped(msg: dict[str, Any]) -> GoalRequest:
    """A geometry_msgs/PoseStamped (what Foxglove's and RViz's goal tools publish)."""
    frame = str(msg.get("header", {}).get("frame_id", ""))
    pose = msg.get("pose", {})
    position = pose.get("position", {})
    x = _coordinate(position.get("x"), "pose.position.x")
    y = _coordinate(position.get("y"), "pose.position.y")
    yaw = yaw_of(pose.get("orientation", {}))
    if not math.isfinite(yaw):
        raise GoalError("pose.orientation: expected finite numbers")
    return GoalRequest(frame, x, y, yaw)


def goal_of_json(body: dict[str, Any], default_frame: str) -> GoalRequest:
    """``{"x", "y", "theta"?, "frame"?}``, ``{"waypoints": [[x, y], ...], "frame"?}`` or
    ``{"path": "figure_eight", "size"?}``."""
    known = {"x", "y", "theta", "frame", "waypoints", "path", "size"}
    unknown = sorted(set(body) - known)
    if unknown:
        raise GoalError(f"{unknown[0]}: unknown field ({', '.join(sorted(known))})")
    frame = body.get("frame", default_frame)
    if not isinstance(frame, str):
        raise GoalError("frame: expected a string")
    if "path" in body:
        return _builtin_path(body, frame)
    if "waypoints" in body:
        return GoalRequest(frame, waypoints=_waypoints(body["waypoints"]))
    yaw = _angle(body["theta"], "theta") if "theta" in body else None
    return GoalRequest(frame, _coordinate(body.get("x"), "x"), _coordinate(body.get("y"), "y"),
                       yaw)


def _builtin_path(body: dict[str, Any], frame: str) -> GoalRequest:
    name = body["path"]
    if name not in BUILTIN_PATHS:
        raise GoalError(f"path: {name!r} is no built-in path ({', '.join(BUILTIN_PATHS)})")
    default, low, high = BUILTIN_PATHS[name]
    size = _finite(body.get("size", default), "size")
    if not low <= size <= high:
        raise GoalError(f"size: {size:g} m is outside {low:g}..{high:g} m")
    return GoalRequest(frame, path=name, size=size)


def _waypoints(raw: Any) -> tuple[tuple[float, float], ...]:
    if not isinstance(raw, list) or not raw or len(raw) > MAX_WAYPOINTS:
        raise GoalError(f"waypoints: expected a list of 1..{MAX_WAYPOINTS} [x, y] pairs")
    out = []
    for i, point in enumerate(raw):
        if not isinstance(point, list) or len(point) != 2:
            raise GoalError(f"waypoints[{i}]: expected [x, y]")
        out.append((_coordinate(point[0], f"waypoints[{i}][0]"),
                    _coordinate(point[1], f"waypoints[{i}][1]")))
    return tuple(out)


def _finite(value: Any, key: str) -> float:
    try:
        return coords.number(value, key)
    except coords.CoordinateError as exc:
        raise GoalError(str(exc)) from None


def _coordinate(value: Any, key: str) -> float:
    """A goal's coordinate through the one validator (finite, within the documented bound)."""
    try:
        return coords.coordinate(value, key)
    except coords.CoordinateError as exc:
        raise GoalError(str(exc)) from None


def _angle(value: Any, key: str) -> float:
    try:
        return coords.angle(value, key)
    except coords.CoordinateError as exc:
        raise GoalError(str(exc)) from None


def path_msg(message: PlanMessage) -> dict[str, Any]:
    """nav_msgs/Path: the plan's points, each heading toward the next."""
    points = message.points
    poses = []
    for i, (x, y) in enumerate(points):
        nxt = points[min(i + 1, len(points) - 1)]
        prev = points[max(i - 1, 0)]
        dx, dy = (nxt - points[i]) if i + 1 < len(points) else (points[i] - prev)
        yaw = math.atan2(dy, dx) if dx or dy else 0.0
        poses.append({"header": header(message.stamp, message.frame_id),
                      "pose": {"position": {"x": float(x), "y": float(y), "z": 0.0},
                               "orientation": quaternion_z(yaw)}})
    return {"header": header(message.stamp, message.frame_id), "poses": poses}
