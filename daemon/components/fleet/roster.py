# The operator's view of the fleet: every robot's latest state, from the router's session.
from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from daemon.components.fleet import keys
from daemon.messages.cdr_read import decode
from daemon.messages.definitions import (
    BATTERY_STATE,
    ODOMETRY,
    POSE_WITH_COVARIANCE_STAMPED,
)

#: the keys the roster decodes (the rest it only counts as a sign of life)
DECODED = {"odom": ODOMETRY, "pose": POSE_WITH_COVARIANCE_STAMPED,
           "battery_state": BATTERY_STATE}


@dataclass
class RobotState:
    """What the operator knows of one robot."""

    robot_id: str
    alive: bool = False
    last_seen: float = 0.0  # wall clock, s
    pose: dict[str, Any] | None = None
    map_pose: bool = False
    health: str = "unknown"
    battery: float | None = None
    estop_engaged: bool | None = None
    info: dict[str, Any] = field(default_factory=dict)
    samples: int = 0
    bytes: int = 0

    def to_json(self, now: float, stale_s: float) -> dict[str, Any]:
        age = now - self.last_seen if self.last_seen else None
        return {"robot_id": self.robot_id, "online": self.alive,
                "stale": age is None or age > stale_s, "health": self.health,
                "pose": self.pose, "battery": self.battery,
                "estop_engaged": self.estop_engaged, "last_seen": self.last_seen or None,
                "age_s": None if age is None else round(age, 3),
                "console": self.info.get("console"),
                "allow_commands": self.info.get("allow_commands"),
                "commands": self.info.get("commands"),
                "samples": self.samples, "bytes": self.bytes}


class Roster:
    """Robots by id, updated from Zenoh threads (one lock), read by the HTTP handlers."""

    def __init__(self, clock: Callable[[], float] = time.time) -> None:
        self.clock = clock
        self.robots: dict[str, RobotState] = {}
        self.malformed = 0
        self._lock = threading.Lock()

    def _robot(self, robot_id: str) -> RobotState:
        robot = self.robots.get(robot_id)
        if robot is None:
            robot = self.robots[robot_id] = RobotState(robot_id)
        return robot

    def on_alive(self, key: str, alive: bool) -> None:
        where = keys.split(key)
        if where is None or where[1] != keys.ALIVE:
            return
        with self._lock:
            robot = self._robot(where[0])
            robot.alive = alive
            if alive:
                robot.last_seen = self.clock()

    def on_sample(self, key: str, payload: bytes) -> None:
        where = keys.split(key)
        if where is None:
            return
        robot_id, name = where
        try:
            update = _reading(name, payload)
        except Exception:
            self.malformed += 1
            return
        with self._lock:
            robot = self._robot(robot_id)
            robot.last_seen = self.clock()
            robot.samples += 1
            robot.bytes += len(payload)
            _apply(robot, name, update)

    def on_status(self, robot_id: str, status: dict[str, Any]) -> None:
        with self._lock:
            member = self._robot(robot_id)
            member.last_seen = self.clock()
            member.estop_engaged = bool(status.get("estop_engaged"))
            if isinstance(status.get("console"), str):
                member.info.setdefault("console", status["console"])
            if isinstance(status.get("health"), str):
                member.health = status["health"]
            if member.pose is None and isinstance(status.get("pose"), dict):
                member.pose = {**status["pose"], "frame": "odom"}

    def snapshot(self, stale_s: float) -> list[dict[str, Any]]:
        now = self.clock()
        with self._lock:
            return [r.to_json(now, stale_s) for r in sorted(self.robots.values(),
                                                             key=lambda r: r.robot_id)]

    def online(self) -> list[str]:
        with self._lock:
            return sorted(r.robot_id for r in self.robots.values() if r.alive)


def _reading(name: str, payload: bytes) -> Any:
    if name == keys.INFO:
        info = json.loads(payload)
        return info if isinstance(info, dict) else {}
    type_name = DECODED.get(name)
    if type_name is None:
        return None
    msg = decode(type_name, payload)
    if name == "odom" or name == "pose":
        pose = msg["pose"]["pose"]
        return {"x": pose["position"]["x"], "y": pose["position"]["y"],
                "theta": _yaw(pose["orientation"]), "frame": msg["header"]["frame_id"]}
    if name == "battery_state":
        pct = msg["percentage"]
        return pct if isinstance(pct, float) and math.isfinite(pct) else None


def _apply(robot: RobotState, name: str, update: Any) -> None:
    if name == keys.INFO:
        robot.info = update
    elif name == "pose":
        robot.pose, robot.map_pose = update, True
    elif name == "odom" and not robot.map_pose:
        robot.pose = update
    elif name == "battery_state":
        robot.battery = update


def _yaw(q: dict[str, float]) -> float:
    return math.atan2(2 * (q["w"] * q["z"] + q["x"] * q["y"]),
                      1 - 2 * (q["y"] ** 2 + q["z"] ** 2))
