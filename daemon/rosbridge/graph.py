# The bridge's topic and service registry: robot topics, client topics, client services.
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from daemon.rosbridge import rosapi
from daemon.rosbridge.outbox import SharedMessage
from daemon.rosbridge.topics import RobotTopic

if TYPE_CHECKING:
    from daemon.rosbridge.session import ClientSession

DAEMON_NODE = "/arbiterd"
ROSAPI_NODE = "/rosapi"
BRIDGE_NODE = "/rosbridge_websocket"


@dataclass(eq=False)
class Topic:
    """One topic: the robot's own (``robot`` set) or one clients advertise to each other."""

    name: str
    type: str
    robot: RobotTopic | None = None
    publishers: dict[ClientSession, str] = field(default_factory=dict)  # client -> its type
    subscribers: set[ClientSession] = field(default_factory=set)
    latched: SharedMessage | None = None

    @property
    def robot_out(self) -> bool:
        return self.robot is not None and self.robot.direction == "out"

    @property
    def robot_in(self) -> bool:
        return self.robot is not None and self.robot.direction == "in"

    def accepts(self, type_name: str) -> bool:
        if self.robot is not None and self.robot.accepts:
            return type_name in self.robot.accepts
        return type_name == self.type


@dataclass(eq=False)
class ProvidedService:
    """A service a client advertised (``advertise_service``); calls are forwarded to it."""

    name: str
    type: str
    provider: ClientSession


@dataclass(eq=False)
class PendingCall:
    """A forwarded call waiting for the provider's ``service_response``."""

    caller: ClientSession
    caller_id: str | int | None
    spelling: str
    service: ProvidedService
    timer: Any = None


class BridgeGraph:
    """Topics, services and the node names rosapi reports."""

    def __init__(self, robot_topics: dict[str, RobotTopic]) -> None:
        self.topics: dict[str, Topic] = {
            name: Topic(name, t.type, t) for name, t in robot_topics.items()}
        self.services: dict[str, ProvidedService] = {}
        self.pending: dict[str, PendingCall] = {}
        self._call_counter = 0

    # -- topics ---------------------------------------------------------------------------

    def relay_topic(self, name: str, type_name: str) -> Topic:
        topic = self.topics.get(name)
        if topic is None:
            topic = self.topics[name] = Topic(name, type_name)
        return topic

    def forget_if_unused(self, topic: Topic) -> None:
        if topic.robot is None and not topic.publishers and not topic.subscribers:
            self.topics.pop(topic.name, None)

    # -- services -------------------------------------------------------------------------

    def next_call_id(self, service: str) -> str:
        self._call_counter += 1
        return f"service_request:{service}:{self._call_counter}"

    # -- rosapi Graph protocol ------------------------------------------------------------------

    def topic_types(self) -> dict[str, str]:
        return {name: self.topics[name].type for name in sorted(self.topics)}

    def publishers(self, topic: str) -> list[str]:
        entry = self.topics.get(topic)
        if entry is None:
            return []
        nodes = [DAEMON_NODE] if entry.robot_out else []
        return nodes + ([BRIDGE_NODE] if entry.publishers else [])

    def subscribers(self, topic: str) -> list[str]:
        entry = self.topics.get(topic)
        if entry is None:
            return []
        nodes = [DAEMON_NODE] if entry.robot_in else []
        return nodes + ([BRIDGE_NODE] if entry.subscribers else [])

    def service_types(self) -> dict[str, str]:
        types = {name: spec[0] for name, spec in rosapi.SERVICES.items()}
        types.update({name: s.type for name, s in self.services.items()})
        return dict(sorted(types.items()))

    def node_names(self) -> list[str]:
        return [DAEMON_NODE, ROSAPI_NODE, BRIDGE_NODE]

    def node_details(self, node: str) -> tuple[list[str], list[str], list[str]]:
        if node == DAEMON_NODE:
            return ([t.name for t in self.topics.values() if t.robot_in],
                    [t.name for t in self.topics.values() if t.robot_out], [])
        if node == ROSAPI_NODE:
            return [], [], list(rosapi.SERVICES)
        return ([t.name for t in self.topics.values() if t.subscribers],
                [t.name for t in self.topics.values() if t.publishers],
                sorted(self.services))
