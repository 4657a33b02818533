# The one topic table: what each component publishes and accepts, for every transport to serve.
from __future__ import annotations

from collections.abc import Awaitable, Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Generic, Literal, TypeVar

from daemon.bus import BusKey

T = TypeVar("T")

#: who may call a route or publish to a topic: anyone; anyone who may stop the robot (a
#: browser's Origin checked, never a token: latching the e-stop); a reader; or a driver (the
#: token, when one is configured)
Access = Literal["open", "stop", "read", "drive"]
ACCESS_LEVELS: tuple[Access, ...] = ("open", "stop", "read", "drive")


@dataclass(frozen=True)
class TopicOut(Generic[T]):
    """A topic the robot publishes: the bus key that feeds it, its ROS name and type, how a
    bus message becomes that ROS message, and where it goes.

    ``rate`` is what the docs say about it ("20 Hz", "per revolution"). ``bridge``: rosbridge
    (and any later transport) serves it; ``record``: the flight recorder writes it. ``state``:
    the latest value is all a new subscriber needs (else every message counts, as for logs).
    ``latched``: every new recording starts with the latest message (health). ``bulk``: large
    messages (scans, maps) that rosbridge sends in the wake-up of the next control tick, after
    the tick, so that no tick waits behind their encoding and sends.
    """

    name: str
    type: str
    bus: BusKey[T]
    convert: Callable[[T], dict[str, Any]]
    rate: str
    bridge: bool = True
    record: bool = True
    state: bool = True
    latched: bool = False
    bulk: bool = False
    record_rate: float = 0.0


@dataclass(frozen=True)
class Refusal:
    """Why an incoming message was not applied. ``repeats``: the same refusal may come at
    command rate (a held key while the e-stop is latched), so a transport says it once a
    while instead of every time."""

    reason: str
    repeats: bool = False


@dataclass(slots=True)
class Inbound:
    """One message arriving on an incoming topic, already checked against its ROS type. Made
    once per message and not changed after (not frozen: a frozen dataclass costs several
    times as much to make, on the command path)."""

    topic: str
    type: str
    msg: dict[str, Any]
    #: the command source it speaks for (``ws:3``), one per client connection
    source: str
    #: who sent it, for logs (``rosbridge client 3 (127.0.0.1)``)
    sender: str
    #: monotonic receipt time (latency starts here)
    t_recv: float
    #: the sender's network address (limits per peer)
    peer: str
    #: the arbiter priority and deadman of its command source (None: the daemon's default)
    priority: int = 10
    timeout_s: float | None = None


InboundHandler = Callable[[Inbound], Awaitable[Refusal | None]]


@dataclass(frozen=True)
class TopicIn:
    """A topic the robot accepts: its ROS type (and other accepted types), who may publish
    to it, and the handler that applies a message or returns a :class:`Refusal`.

    ``moves``: a command source: when the publisher goes away (unadvertises, disconnects), the
    robot brakes if that source was in charge. ``access_for``: when what a message may do
    depends on the message (the e-stop: latching is ``stop``, releasing ``drive``), the access
    one message needs, checked once its type is; ``access`` is then what advertising and
    publishing need before that, the least of them. ``required``: dotted field paths a
    message must carry as sent (``pose.position``): a transport refuses one without them
    before the type's defaults would fill them in (a goal without a position is no goal to
    (0, 0)); see :func:`daemon.coords.missing_required`.
    """

    name: str
    type: str
    handler: InboundHandler
    access: Access = "drive"
    accepts: tuple[str, ...] = ()
    moves: bool = False
    access_for: Callable[[dict[str, Any]], Access] | None = None
    required: tuple[str, ...] = ()

    def accepted_types(self) -> tuple[str, ...]:
        return self.accepts or (self.type,)


Topic = TopicOut[Any] | TopicIn


class TopicTable:
    """Every topic the running daemon's components declared, by ROS name (one owner each)."""

    def __init__(self) -> None:
        self._topics: dict[str, Topic] = {}
        self._owners: dict[str, str] = {}

    def declare(self, owner: str, topics: Iterable[Topic]) -> None:
        for topic in topics:
            if topic.name in self._topics:
                raise ValueError(f"topic {topic.name} is declared by both "
                                 f"{self._owners[topic.name]} and {owner}")
            self._topics[topic.name] = topic
            self._owners[topic.name] = owner

    def owner(self, name: str) -> str:
        return self._owners[name]

    def __iter__(self) -> Iterator[Topic]:
        return iter(self._topics.values())

    def __contains__(self, name: object) -> bool:
        return name in self._topics

    def get(self, name: str) -> Topic | None:
        return self._topics.get(name)

    def outgoing(self) -> list[TopicOut[Any]]:
        return [t for t in self._topics.values() if isinstance(t, TopicOut)]

    def incoming(self) -> list[TopicIn]:
        return [t for t in self._topics.values() if isinstance(t, TopicIn)]

    def bridged(self) -> list[Topic]:
        """What rosbridge serves: every incoming topic and the outgoing ones marked ``bridge``."""
        return [t for t in self._topics.values() if isinstance(t, TopicIn) or t.bridge]

    def recorded(self) -> list[TopicOut[Any]]:
        return [t for t in self.outgoing() if t.record]
