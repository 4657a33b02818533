# The robot's own topics as rosbridge serves them (until the component topic table).
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from daemon.messages.convert import (
    json_string_msg,
    latency_msg,
    log_msg,
    odometry_msg,
    scan_msg,
    tf_msg,
)
from daemon.messages.definitions import (
    BOOL,
    LASER_SCAN,
    LOG,
    ODOMETRY,
    STRING,
    TF_MESSAGE,
    TWIST,
    TWIST_STAMPED,
)

AUTONOMY_MODE = "/autonomy/mode"
# the topics clients publish to that move the robot (a token is needed when configured)
COMMAND_TOPICS = ("/cmd_vel", "/stamped_cmd_vel", "/estop", AUTONOMY_MODE)


@dataclass(frozen=True)
class RobotTopic:
    """A topic the daemon itself publishes (``out``) or consumes (``in``)."""

    name: str
    type: str
    direction: str
    bus: str | None = None  # bus topic feeding an outgoing topic
    convert: Callable[[Any], dict[str, Any]] | None = None
    state: bool = True  # latest value is all a client needs (else: every message counts)
    accepts: tuple[str, ...] = ()  # extra accepted types on an incoming topic


def robot_topics(*, sim: bool, odom_tf: bool) -> dict[str, RobotTopic]:
    """The topic table of DESIGN.md for this configuration."""
    topics = [
        RobotTopic("/cmd_vel", TWIST, "in", accepts=(TWIST, TWIST_STAMPED)),
        RobotTopic("/stamped_cmd_vel", STRING, "in"),
        RobotTopic("/estop", BOOL, "in"),
        RobotTopic(AUTONOMY_MODE, STRING, "in"),
        RobotTopic("/autonomy/state", STRING, "out", "autonomy_state", json_string_msg),
        RobotTopic("/collision_monitor/state", STRING, "out", "collision_monitor_state",
                   json_string_msg),
        RobotTopic("/odom", ODOMETRY, "out", "odom", odometry_msg),
        RobotTopic("/scan", LASER_SCAN, "out", "scan", scan_msg),
        RobotTopic("/robot_info", STRING, "out", "robot_info", json_string_msg),
        RobotTopic("/latency_reports", STRING, "out", "latency_report", latency_msg,
                   state=False),
        RobotTopic("/rosout", LOG, "out", None, log_msg, state=False),
    ]
    if odom_tf:
        topics.append(RobotTopic("/tf", TF_MESSAGE, "out", "odom", tf_msg))
    if sim:
        topics.append(RobotTopic("/odom_ground_truth", ODOMETRY, "out", "odom_ground_truth",
                                 odometry_msg))
    return {t.name: t for t in topics}
