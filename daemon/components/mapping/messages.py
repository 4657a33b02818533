# The mapping component's ROS messages: /map, /pose, and poses read from /initialpose or JSON.
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from daemon import coords
from daemon.components.mapping.mapfile import MapData
from daemon.messages.convert import header, quaternion_z
from slam.mapper import ScanResult
from slam.pose import Pose2


@dataclass(frozen=True, slots=True)
class MapMessage:
    """The map as published: when, in which frame."""

    stamp: float
    frame_id: str
    grid: MapData


@dataclass(frozen=True, slots=True)
class MapPose:
    """The robot's pose in the map after one revolution."""

    stamp: float
    frame_id: str
    result: ScanResult


def _pose(x: float, y: float, theta: float) -> dict[str, Any]:
    return {"position": {"x": x, "y": y, "z": 0.0}, "orientation": quaternion_z(theta)}


def map_msg(message: MapMessage) -> dict[str, Any]:
    grid = message.grid
    return {"header": header(message.stamp, message.frame_id),
            "info": {"map_load_time": header(message.stamp, "")["stamp"],
                     "resolution": grid.resolution, "width": grid.width,
                     "height": grid.height,
                     "origin": _pose(grid.origin_x, grid.origin_y, 0.0)},
            "data": grid.occupancy.ravel()}


def pose_msg(message: MapPose) -> dict[str, Any]:
    """geometry_msgs/PoseWithCovarianceStamped: the 3x3 (x, y, yaw) covariance spread into
    the 6x6 one (z, roll and pitch 0)."""
    result = message.result
    covariance = [0.0] * 36
    slots = (0, 1, 5)
    for i, row in enumerate(slots):
        for j, column in enumerate(slots):
            covariance[row * 6 + column] = float(result.covariance[i * 3 + j])
    return {"header": header(message.stamp, message.frame_id),
            "pose": {"pose": _pose(*result.pose), "covariance": covariance}}


def yaw_of(orientation: dict[str, Any]) -> float:
    """The heading of a quaternion (a planar robot: rotation about z)."""
    x, y, z, w = (float(orientation.get(k, d)) for k, d in
                  (("x", 0.0), ("y", 0.0), ("z", 0.0), ("w", 1.0)))
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def pose_of(msg: dict[str, Any], map_frame: str) -> Pose2:
    """The pose of a PoseWithCovarianceStamped or PoseStamped in ``map_frame``; a pose in
    another frame or with a non-finite number is refused, naming it."""
    frame = msg.get("header", {}).get("frame_id", "")
    if frame != map_frame:
        raise ValueError(f"header.frame_id is {frame!r}: a pose in the map is expected "
                         f"(frame {map_frame!r})")
    outer = msg.get("pose", {})
    inner = "pose" in outer
    pose = outer.get("pose", outer)
    at = "pose.pose" if inner else "pose"
    position = pose.get("position", {})
    x = coords.coordinate(position.get("x"), f"{at}.position.x")
    y = coords.coordinate(position.get("y"), f"{at}.position.y")
    theta = yaw_of(pose.get("orientation", {}))
    if not math.isfinite(theta):
        raise ValueError(f"{at}.orientation: expected finite numbers")
    return (x, y, theta)


def pose_of_json(body: Any) -> Pose2:
    """``{"x": m, "y": m, "theta": rad}`` (or ``"heading_deg"``), checked."""
    if not isinstance(body, dict):
        raise ValueError("expected {\"x\": m, \"y\": m, \"theta\": rad}")
    unknown = sorted(set(body) - {"x", "y", "theta", "heading_deg"})
    if unknown:
        raise ValueError(f"{unknown[0]}: unknown field (x, y, theta or heading_deg)")
    x, y = coords.coordinate(body.get("x"), "x"), coords.coordinate(body.get("y"), "y")
    if "heading_deg" in body:
        theta = math.radians(coords.number(body["heading_deg"], "heading_deg"))
    else:
        theta = coords.angle(body.get("theta", 0.0), "theta")
    if abs(theta) > coords.MAX_ANGLE_RAD:
        raise coords.CoordinateError("heading_deg", "beyond the largest angle taken")
    return (x, y, theta)
