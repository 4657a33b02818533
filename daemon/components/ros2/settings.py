# [ros2]: the ROS 2 face's switch, graph identity, topic selection, QoS and command opt-in.
from __future__ import annotations

import re
from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option

DISTROS = ("humble", "jazzy", "kilted")
DISCOVERY = ("auto", "localhost", "subnet")
_NODE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_NAMESPACE = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)*/?$")
_TOPIC = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)+$")


def _node_name(value: object) -> str | None:
    return None if _NODE_NAME.match(str(value)) else "a ROS node name: letters, digits, _"


def _namespace(value: object) -> str | None:
    return None if _NAMESPACE.match(str(value)) else "a ROS namespace such as '' or '/robot1'"


def _topics(value: object) -> str | None:
    bad = [t for t in value if not _TOPIC.match(str(t))] if isinstance(value, list) else []
    return f"{bad[0]!r} is not an absolute ROS topic name such as '/scan'" if bad else None


@dataclass(frozen=True)
class Ros2Settings(SectionSettings, section="ros2"):
    enabled: bool = option(False, "join the ROS 2 graph over DDS as a node of its own (needs the "
                           "ros2 extra: cyclonedds; docs/ros2.md)")
    domain_id: int = option(-1, "ROS domain id (-1: ROS_DOMAIN_ID from the environment, else 0)",
                            minval=-1, maxval=232)
    namespace: str = option("", "node namespace; it prefixes every topic ('' or '/robot1')",
                            check=_namespace)
    node_name: str = option("arbiterd", "the node name other ROS 2 nodes see", check=_node_name)
    distro: str = option("jazzy", "the ROS 2 release of the other nodes (layout of the node "
                         "announcement; kilted: no type information)", choices=DISTROS)
    discovery: str = option("auto", "who finds the node: localhost (this machine only), subnet "
                            "(the network), auto (ROS_AUTOMATIC_DISCOVERY_RANGE / "
                            "ROS_LOCALHOST_ONLY from the environment, else subnet)",
                            choices=DISCOVERY)
    topics: list[str] = option([], "topics served (published and accepted); [] = every topic of "
                               "the topic table", check=_topics)
    best_effort: list[str] = option(["/scan"], "published best effort (sensor data QoS); the "
                                    "others reliable", check=_topics)
    transient_local: list[str] = option(["/tf_static", "/map"], "published transient local (a "
                                        "late subscriber gets the latest)", check=_topics)
    depth: int = option(10, "history depth (keep last) of each topic", minval=1, maxval=1000)
    allow_commands: bool = option(False, "accept commands (/cmd_vel, ...) from DDS: anyone who "
                                  "reaches the DDS domain may then drive the robot")
    command_priority: int = option(10, "arbiter priority of DDS commands (rosbridge and HTTP "
                                   "clients: 10)", minval=0, maxval=100)
    command_timeout: float = option(0.0, "deadman of DDS commands, s (0: [control] "
                                    "cmd_vel_timeout)", minval=0.0, maxval=10.0)
    queue: int = option(64, "samples waiting for the DDS writer thread; beyond it the oldest is "
                        "dropped", minval=4, maxval=10000)
    security: str = option("", "DDS Security: the directory of an SROS2 enclave (cert.pem, "
                           "key.pem, identity_ca.cert.pem, permissions_ca.cert.pem, "
                           "governance.p7s, permissions.p7s); '' = none (docs/ros2.md)")
    max_rate: float = option(200.0, "incoming samples handled per second and topic (a burst of a "
                             "fifth of it); beyond it the newest are kept and the rest refused as "
                             "overload", above=0.0, maxval=100000.0)
