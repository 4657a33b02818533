# The bridge's graph: robot and client topics, client services, forwarded calls, and fan-out.
from __future__ import annotations

import asyncio
import itertools
from collections import Counter
from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

from daemon.bus import BusKey
from daemon.components.rosbridge import rosapi
from daemon.components.rosbridge.codec import Id
from daemon.components.rosbridge.outbox import SharedMessage
from daemon.topics import Topic as RobotTopic
from daemon.topics import TopicIn, TopicOut

DAEMON_NODE = "/arbiterd"
ROSAPI_NODE = "/rosapi"
BRIDGE_NODE = "/rosbridge_websocket"


class Peer(Hashable, Protocol):
    """What the graph needs from a connected client (a ``ClientSession``)."""

    def deliver(self, topic: str, message: SharedMessage) -> None:
        """Queue a message of a subscribed topic (runs inside the publisher: O(1))."""

    def service_response(self, spelling: str, values: Any, result: bool, rid: Id,
                         fragment_size: int | None = None) -> None:
        """Answer one of this client's service calls."""

    def reply(self, body: dict[str, Any]) -> None:
        """Send this client a request (a forwarded ``call_service``)."""

    def status(self, level: str, message: str, rid: Id = None) -> None:
        """Send this client a ``status`` message."""


@dataclass(eq=False)
class Topic:
    """One topic: the robot's own (``robot`` set) or one clients advertise to each other."""

    name: str
    type: str
    robot: RobotTopic | None = None
    publishers: dict[Peer, str] = field(default_factory=dict)  # client -> its type
    subscribers: set[Peer] = field(default_factory=set)
    latched: SharedMessage | None = None

    @property
    def robot_out(self) -> bool:
        return isinstance(self.robot, TopicOut)

    @property
    def robot_in(self) -> bool:
        return isinstance(self.robot, TopicIn)

    def accepts(self, type_name: str) -> bool:
        if isinstance(self.robot, TopicIn):
            return type_name in self.robot.accepted_types()
        return type_name == self.type


@dataclass(eq=False)
class ProvidedService:
    """A service a client advertised (``advertise_service``); calls are forwarded to it."""

    name: str
    type: str
    provider: Peer


@dataclass(eq=False)
class PendingCall:
    """A forwarded call waiting for the provider's ``service_response``."""

    caller: Peer
    caller_id: Id
    spelling: str
    service: ProvidedService
    timer: asyncio.TimerHandle | None = None


class BridgeGraph:
    """Topics, services and forwarded calls of every client, and the node names rosapi
    reports. ``latest(bus_key)`` gives the robot's latest state for a new subscriber.
    Every change bumps ``version``; the sorted views rosapi asks for are kept per version."""

    def __init__(self, robot_topics: Iterable[RobotTopic],
                 latest: Callable[[BusKey[Any]], Any] = lambda key: None) -> None:
        self.topics: dict[str, Topic] = {t.name: Topic(t.name, t.type, t) for t in robot_topics}
        self.services: dict[str, ProvidedService] = {}
        self.pending: dict[str, PendingCall] = {}
        self.version = 0
        self._latest = latest
        self._call_numbers = itertools.count(1)
        self._services_of: Counter[Peer] = Counter()
        self._calls_of: Counter[Peer] = Counter()
        self._views: dict[str, tuple[int, dict[str, str]]] = {}
        #: told ``(topic, True)`` when one of the robot's topics gets its first subscriber and
        #: ``(topic, False)`` when it loses its last (the server listens to the bus meanwhile)
        self.on_watch: Callable[[Topic, bool], None] = lambda topic, watched: None

    # -- topics ---------------------------------------------------------------------------

    def topic(self, name: str) -> Topic | None:
        return self.topics.get(name)

    def add_publisher(self, peer: Peer, name: str, type_name: str) -> Topic:
        topic = self._topic_for(name, type_name)
        topic.publishers[peer] = type_name
        return topic

    def remove_publisher(self, peer: Peer, name: str) -> None:
        topic = self.topics.get(name)
        if topic is not None:
            topic.publishers.pop(peer, None)
            self._forget_if_unused(topic)

    def add_subscriber(self, peer: Peer, name: str, type_name: str) -> Topic:
        """Subscribe ``peer``; a first subscription gets the latched or latest message."""
        topic = self._topic_for(name, type_name)
        if peer not in topic.subscribers:
            topic.subscribers.add(peer)
            if len(topic.subscribers) == 1 and topic.robot_out:
                self.on_watch(topic, True)
            self._send_latest(topic, peer)
        return topic

    def remove_subscriber(self, peer: Peer, name: str) -> None:
        topic = self.topics.get(name)
        if topic is not None:
            self._unsubscribe(topic, peer)
            self._forget_if_unused(topic)

    def _unsubscribe(self, topic: Topic, peer: Peer) -> None:
        if peer in topic.subscribers:
            topic.subscribers.discard(peer)
            if not topic.subscribers and topic.robot_out:
                self.on_watch(topic, False)

    def fan_out(self, topic: Topic, shared: SharedMessage) -> None:
        for peer in topic.subscribers:
            peer.deliver(topic.name, shared)

    def publish(self, topic: Topic, shared: SharedMessage, *, latch: bool = False) -> None:
        """A client's message on a topic: kept for late subscribers when latched."""
        if latch:
            topic.latched = shared
        self.fan_out(topic, shared)

    def _topic_for(self, name: str, type_name: str) -> Topic:
        topic = self.topics.get(name)
        if topic is None:
            topic = self.topics[name] = Topic(name, type_name)
            self.version += 1
        return topic

    def _send_latest(self, topic: Topic, peer: Peer) -> None:
        if topic.latched is not None:
            peer.deliver(topic.name, topic.latched)
            return
        robot = topic.robot
        if not isinstance(robot, TopicOut) or not robot.state:
            return
        latest = self._latest(robot.bus)
        if latest is not None:
            peer.deliver(topic.name, SharedMessage(topic.name, latest, robot.convert))

    def _forget_if_unused(self, topic: Topic) -> None:
        if topic.robot is None and not topic.publishers and not topic.subscribers:
            self.topics.pop(topic.name, None)
            self.version += 1

    # -- client-provided services -----------------------------------------------------------

    def service(self, name: str) -> ProvidedService | None:
        return self.services.get(name)

    def services_of(self, peer: Peer) -> int:
        return self._services_of[peer]

    def advertise_service(self, peer: Peer, name: str, type_name: str) -> None:
        """``peer`` provides ``name`` now; calls waiting for an earlier provider fail."""
        old = self.services.get(name)
        if old is not None and old.provider is peer:
            old.type = type_name
            self.version += 1
            return
        if old is not None:
            self.withdraw_service(old, f"Service {name} was re-advertised")
        self.services[name] = ProvidedService(name, type_name, peer)
        self._services_of[peer] += 1
        self.version += 1

    def withdraw_service(self, service: ProvidedService, reason: str) -> None:
        if self.services.get(service.name) is service:
            del self.services[service.name]
            self._count(self._services_of, service.provider, -1)
            self.version += 1
        for call_id, pending in list(self.pending.items()):
            if pending.service is service:
                self.fail_call(call_id, reason)

    # -- forwarded calls ------------------------------------------------------------------

    def calls_of(self, caller: Peer) -> int:
        return self._calls_of[caller]

    def forward_call(self, caller: Peer, caller_id: Id, spelling: str,
                     service: ProvidedService, args: Any, timeout_s: float,
                     timeout_reason: str) -> str:
        """Send the call to the provider under a new id; the answer goes back to ``caller``,
        or ``timeout_reason`` (a failed response and a status error) after ``timeout_s``."""
        call_id = f"service_request:{service.name}:{next(self._call_numbers)}"
        pending = self.pending[call_id] = PendingCall(caller, caller_id, spelling, service)
        self._calls_of[caller] += 1
        pending.timer = asyncio.get_running_loop().call_later(
            timeout_s, self._time_out, call_id, timeout_reason)
        service.provider.reply({"op": "call_service", "id": call_id, "service": service.name,
                                "args": args})
        return call_id

    def _time_out(self, call_id: str, reason: str) -> None:
        pending = self.pending.get(call_id)
        if pending is not None:
            self.fail_call(call_id, reason)
            pending.caller.status("error", reason, pending.caller_id)

    def answer_call(self, provider: Peer, call_id: str, values: Any, result: bool) -> bool:
        """The provider's answer to ``call_id``; False when no such call waits for it."""
        pending = self.pending.get(call_id)
        if pending is None or pending.service.provider is not provider:
            return False
        self._forget_call(call_id)
        pending.caller.service_response(pending.spelling, values, result, pending.caller_id)
        return True

    def fail_call(self, call_id: str, reason: str) -> None:
        pending = self._forget_call(call_id)
        if pending is not None:
            pending.caller.service_response(pending.spelling, reason, False, pending.caller_id)

    def _forget_call(self, call_id: str) -> PendingCall | None:
        pending = self.pending.pop(call_id, None)
        if pending is not None:
            self._count(self._calls_of, pending.caller, -1)
            if pending.timer is not None:
                pending.timer.cancel()
        return pending

    @staticmethod
    def _count(counter: Counter[Peer], peer: Peer, delta: int) -> None:
        counter[peer] += delta
        if counter[peer] <= 0:
            del counter[peer]

    # -- a client leaves ------------------------------------------------------------------

    def forget(self, peer: Peer) -> None:
        """Everything ``peer`` set up goes: its topics, services and calls."""
        for topic in [t for t in self.topics.values()
                      if peer in t.publishers or peer in t.subscribers]:
            topic.publishers.pop(peer, None)
            self._unsubscribe(topic, peer)
            self._forget_if_unused(topic)
        for service in [s for s in self.services.values() if s.provider is peer]:
            self.withdraw_service(service, f"Service {service.name} was unadvertised")
        for call_id, pending in list(self.pending.items()):
            if pending.caller is peer:
                self._forget_call(call_id)

    # -- rosapi Graph protocol --------------------------------------------------------------

    def topic_types(self) -> dict[str, str]:
        return self._view("topics", lambda: {
            name: self.topics[name].type for name in sorted(self.topics)})

    def _view(self, name: str, build: Callable[[], dict[str, str]]) -> dict[str, str]:
        """A sorted view, built once per graph version (callers must not change it)."""
        cached = self._views.get(name)
        if cached is None or cached[0] != self.version:
            cached = self._views[name] = (self.version, build())
        return cached[1]

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
        def build() -> dict[str, str]:
            types = {name: spec[0] for name, spec in rosapi.SERVICES.items()}
            types.update({name: s.type for name, s in self.services.items()})
            return dict(sorted(types.items()))

        return self._view("services", build)

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
