# The fleet's Zenoh key space: one prefix per robot, its telemetry, queryables and commands.
from __future__ import annotations

PREFIX = "arbiterd"
#: the robot's liveliness token
ALIVE = "alive"
#: JSON: robot_id, console URL (a put at join, then at every refresh)
INFO = "info"
#: queryables: ``srv/status`` (JSON), ``srv/map`` (zlib CDR), ``srv/recordings`` (JSON)
SERVICE = "srv"
#: commands: ``cmd/<incoming ROS topic>`` as a query whose payload is the message's CDR
COMMAND = "cmd"
#: the table topics the robot publishes, by fleet key (the ROS name without its slash)
TELEMETRY = {"odom": "/odom", "pose": "/pose", "scan": "/scan", "map": "/map",
             "battery_state": "/battery_state", "diagnostics": "/diagnostics",
             "rosout": "/rosout"}
#: a published map is zlib-compressed CDR (the encoding names it)
MAP_ENCODING = "application/cdr+zlib"
CDR_ENCODING = "application/cdr"
JSON_ENCODING = "application/json"


def robot_key(robot_id: str, *parts: str) -> str:
    return "/".join((PREFIX, robot_id, *parts))


def topic_key(robot_id: str, topic: str) -> str:
    """``/odom`` of robot r1 -> ``arbiterd/r1/odom``."""
    return robot_key(robot_id, topic.lstrip("/"))


def command_key(robot_id: str, topic: str) -> str:
    """The command key of an incoming topic (``*`` as robot_id: every robot)."""
    return robot_key(robot_id, COMMAND, topic.lstrip("/"))


def split(key: str) -> tuple[str, str] | None:
    """``arbiterd/r1/odom`` -> ``("r1", "odom")``; None outside the key space."""
    parts = key.split("/", 2)
    if len(parts) != 3 or parts[0] != PREFIX:
        return None
    return parts[1], parts[2]
