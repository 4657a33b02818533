# The "ros2" component: the topic table served to the ROS 2 graph over DDS, as a node of its own.
from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from base.rates import TokenBucket
from daemon.component import BaseComponent, ComponentSpec, DaemonContext
from daemon.components.ros2 import announce, names, security
from daemon.components.ros2.dds import (
    ANNOUNCE_QOS,
    DdsError,
    DdsNode,
    QosSpec,
    announcement_type,
    available,
    idl_type,
    libddsc_path,
)
from daemon.components.ros2.inlet import Inlet
from daemon.components.ros2.outlet import Outlet
from daemon.components.ros2.settings import Ros2Settings
from daemon.health import Health
from daemon.messages import cdr, typehash
from daemon.messages.cdr_read import decode
from daemon.messages.definitions import LASER_SCAN
from daemon.messages.msgtypes import MessageError, check_message
from daemon.messages.scans import scan_cdr
from daemon.topics import Inbound, TopicIn, TopicOut

log = logging.getLogger("arbiterd.ros2")

SOURCE = "ros2"
#: why incoming samples were not applied, as counted in health
REFUSALS = ("not_allowed", "malformed", "invalid", "refused", "foreign_type", "duplicate_node",
            "overload")
#: samples handed to the event loop and not yet handled; beyond it they are dropped
MAX_PENDING = 64
REFUSAL_LOG_S = 10.0


@dataclass
class Outgoing:
    """A published topic: its DDS writer and how many DDS readers match it."""

    topic: TopicOut[Any]
    writer: Any
    encode: Callable[[Any], bytes]
    keep: bool  # transient local: written even with nobody matched (late joiners get it)
    matched: int = 0
    published: int = 0


class Ros2Face(BaseComponent):
    """A DDS participant announced as node ``namespace/node_name``: every topic of the table
    (or the configured ones) out from the bus, and the incoming ones to their handlers as the
    command source ``ros2``. The reader thread (:class:`Inlet`) only takes samples and hands
    them to the event loop; the event loop only queues samples for the writer thread."""

    name = "ros2"
    core = False

    def __init__(self, ctx: DaemonContext, settings: Ros2Settings,
                 enclave: security.Enclave | None = None) -> None:
        self.ctx = ctx
        self.settings = settings
        self.enclave = enclave
        self.domain = names.domain_id(settings.domain_id)
        self.localhost = names.localhost_only(settings.discovery)
        self.gid_size = announce.GID_SIZE[settings.distro]
        self.namespace = settings.namespace.rstrip("/") or ""
        self.node_label = f"{self.namespace}/{settings.node_name}"
        self.node: DdsNode | None = None
        self.outlet: Outlet | None = None
        self.inlet: Inlet | None = None
        self.outgoing: dict[str, Outgoing] = {}
        self.incoming: dict[str, TopicIn] = {}
        self.received = 0
        self.accepted = 0
        self.overflow = 0
        self.refused = dict.fromkeys(REFUSALS, 0)
        self.last_refusal = ""
        self.duplicates: frozenset[bytes] = frozenset()
        self._foreign: set[bytes] = set()
        self._pending = 0
        self._budgets: dict[str, TokenBucket] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self._logged: dict[str, float] = {}
        self._unsubscribe: list[Callable[[], None]] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._discovery_reader: Any = None
        self._publications: Any = None

    # -- lifecycle ------------------------------------------------------------------------------

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        outs, ins = self._selected()
        try:
            self.node = await asyncio.to_thread(self._build, outs, ins)
        except DdsError as exc:
            if self.enclave is None:
                raise
            raise OSError(f"[ros2] security: Cyclone DDS refused the enclave {self.enclave.path} "
                          f"({exc}); check its signatures, the permissions' subject and the "
                          "governance's domains (docs/ros2.md)") from None
        self.outlet = Outlet(self.settings.queue, idle=self._poll_discovery)
        self.outlet.start()
        assert self.inlet is not None
        self.inlet.start()
        self.outlet.put(self._announce)
        for out in self.outgoing.values():
            self._unsubscribe.append(self.ctx.bus.subscribe(out.topic.bus, self._feeder(out)))
        log.info("ros2: node %s in domain %d (%s discovery, %s), %d topics out, %d in%s",
                 self.node_label, self.domain, "localhost" if self.localhost else "subnet",
                 self.settings.distro, len(self.outgoing), len(self.incoming),
                 "" if self.settings.allow_commands else "; commands from DDS refused "
                 "([ros2] allow_commands = false)")

    async def stop(self) -> None:
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        self._unsubscribe.clear()
        for thread in (self.outlet, self.inlet):
            if thread is not None:
                await asyncio.to_thread(thread.close)
        for task in list(self._tasks):
            task.cancel()
        await self.ctx.robot.drop_source(SOURCE)
        if self.node is not None:
            await asyncio.to_thread(self.node.close)
            self.node = None

    def _selected(self) -> tuple[list[TopicOut[Any]], list[TopicIn]]:
        wanted = set(self.settings.topics)
        chosen = [t for t in self.ctx.topics if _served(t) and (not wanted or t.name in wanted)]
        return ([t for t in chosen if isinstance(t, TopicOut)],
                [t for t in chosen if isinstance(t, TopicIn)])

    def _qos(self, name: str) -> QosSpec:
        return QosSpec(reliable=name not in self.settings.best_effort,
                       transient_local=name in self.settings.transient_local,
                       depth=self.settings.depth)

    def _dds_name(self, name: str) -> str:
        return names.dds_topic(self.namespace, name)

    def _build(self, outs: list[TopicOut[Any]], ins: list[TopicIn]) -> DdsNode:
        """The participant and its endpoints (in a thread: DDS set-up is not the loop's)."""
        xml = "" if self.enclave is None else security.cyclone_xml(self.enclave, libddsc_path())
        node = DdsNode(self.domain, self.localhost, self.settings.distro != "kilted", xml)
        for topic in outs:
            qos = self._qos(topic.name)
            writer = node.writer(self._dds_name(topic.name), idl_type(topic.type), qos,
                                 _user_data(topic.type))
            self.outgoing[topic.name] = Outgoing(topic, writer, _encoder(topic),
                                                 qos.transient_local)
        self.inlet = Inlet(node, self._on_data, self._on_unmatched)
        for inbound in ins:
            self.incoming[inbound.name] = inbound
            reader = node.reader(self._dds_name(inbound.name), idl_type(inbound.type),
                                 self._qos(inbound.name), _user_data(inbound.type))
            self.inlet.add(inbound, reader, watch_publishers=inbound.moves)
        info_type = announcement_type(self.gid_size)
        self._announcer = node.writer(announce.TOPIC, info_type, ANNOUNCE_QOS)
        self._discovery_reader = node.reader(announce.TOPIC, info_type, ANNOUNCE_QOS)
        self._publications = node.publications_reader()
        return node

    # -- out: bus -> writer thread -> DDS --------------------------------------------------------

    def _feeder(self, out: Outgoing) -> Callable[[Any], None]:
        outlet, node = self.outlet, self.node
        assert outlet is not None and node is not None

        def on_message(message: Any) -> None:  # in the publisher (control tick): O(1)
            if out.matched or out.keep:
                outlet.put(lambda: self._write(node, out, message))

        return on_message

    def _write(self, node: DdsNode, out: Outgoing, message: Any) -> None:  # writer thread
        node.write(out.writer, out.encode(message))
        out.published += 1

    def _announce(self) -> None:  # writer thread
        node = self.node
        assert node is not None
        readers = [node.guid_of(e) for e in node._entities
                   if e is not self._discovery_reader and e is not self._publications
                   and hasattr(e, "take")]
        writers = [node.guid_of(o.writer) for o in self.outgoing.values()]
        info = announce.NodeInfo(self.namespace or "/", self.settings.node_name, readers,
                                 writers)
        node.write(self._announcer, announce.encode(node.guid, [info], self.gid_size))

    # -- discovery: the same node name elsewhere, foreign types on our topics ---------------------

    def _poll_discovery(self) -> None:  # writer thread, every quarter second
        node = self.node
        if node is None:
            return
        for out in self.outgoing.values():
            out.matched = node.publication_matches(out.writer)
        self._check_nodes(node)
        self._check_publications(node)

    def _check_nodes(self, node: DdsNode) -> None:
        duplicates = set(self.duplicates)
        for data, _ in node.take_raw(self._discovery_reader, 64):
            try:
                participant, nodes = _announcement(data, self.gid_size)
            except cdr.CdrError:
                continue
            if participant == node.guid:
                continue
            if any(n.name == self.settings.node_name and
                   n.namespace.rstrip("/") == self.namespace for n in nodes):
                if participant not in duplicates:
                    self._from_thread(self._refuse, "duplicate_node",
                                      f"another participant announces the node "
                                      f"{self.node_label}; DDS commands are refused")
                duplicates.add(participant)
            else:
                duplicates.discard(participant)
        self.duplicates = frozenset(duplicates)

    def _check_publications(self, node: DdsNode) -> None:
        expected = {self._dds_name(t.name): t.type for t in self.incoming.values()}
        for endpoint in self._publications.take(N=64):
            topic_type = expected.get(getattr(endpoint, "topic_name", ""))
            key = bytes(endpoint.key.bytes)
            if topic_type is None or key in self._foreign:
                continue
            if endpoint.type_name != names.dds_type(topic_type):
                self._foreign.add(key)
                self._from_thread(self._refuse, "foreign_type",
                                  f"a writer of {endpoint.type_name} on {endpoint.topic_name} "
                                  f"(it takes {names.dds_type(topic_type)})")

    def _from_thread(self, callback: Callable[..., None], *args: Any) -> None:
        if self._loop is not None:
            self._loop.call_soon_threadsafe(callback, *args)

    # -- in: reader thread -> event loop -> the topic's handler ----------------------------------

    def _on_data(self, topic: TopicIn, samples: list[bytes]) -> None:  # the reader thread
        """Hand a take to the event loop: at most ``max_rate`` a second per topic (the newest
        of a take; a flood is refused as overload here, not by the event loop)."""
        self.received += len(samples)
        allowed = self._budget(topic).take_up_to(len(samples))
        if allowed < len(samples):
            self._from_thread(self._refuse, "overload",
                              f"{topic.name}: more than {self.settings.max_rate:g} samples a "
                              "second ([ros2] max_rate)", len(samples) - allowed)
            samples = samples[len(samples) - allowed:]
            if not samples:
                return
        if self._pending >= MAX_PENDING:
            self.overflow += len(samples)
            return
        self._pending += 1
        self._from_thread(self._on_samples, topic, samples, time.monotonic())

    def _budget(self, topic: TopicIn) -> TokenBucket:
        budget = self._budgets.get(topic.name)
        if budget is None:
            rate = self.settings.max_rate
            budget = self._budgets[topic.name] = TokenBucket(rate, max(1.0, rate / 5),
                                                             time.monotonic)
        return budget

    def _on_unmatched(self, topic: TopicIn) -> None:  # the reader thread
        """The last publisher of a command topic went away: brake."""
        self._from_thread(self._brake)

    def _brake(self) -> None:
        self._spawn(self.ctx.robot.drop_source(SOURCE))

    def _on_samples(self, topic: TopicIn, samples: list[bytes], t_recv: float) -> None:
        self._pending -= 1
        for data in samples:
            msg = self._screen(topic, data)
            if msg is not None:
                self._spawn(self._deliver(topic, msg, t_recv))

    def _screen(self, topic: TopicIn, data: bytes) -> dict[str, Any] | None:
        """The message when it may go to the handler; else the refusal is counted."""
        try:
            msg = check_message(topic.type, decode(topic.type, data))
        except (cdr.CdrError, MessageError) as exc:
            self._refuse("malformed", f"{topic.name}: {exc}")
            return None
        need = topic.access_for(msg) if topic.access_for is not None else topic.access
        if need == "drive" and not self.settings.allow_commands:
            self._refuse("not_allowed", f"{topic.name}: commands from DDS are off "
                         "([ros2] allow_commands = false)")
            return None
        if need == "drive" and self.duplicates:
            self._refuse("duplicate_node", f"{topic.name}: another participant "
                         f"announces the node {self.node_label}")
            return None
        return msg

    async def _deliver(self, topic: TopicIn, msg: dict[str, Any], t_recv: float) -> None:
        timeout = self.settings.command_timeout or None
        refusal = await topic.handler(Inbound(
            topic.name, topic.type, msg, SOURCE, f"DDS node {self.node_label}", t_recv, "dds",
            self.settings.command_priority, timeout))
        if refusal is None:
            self.accepted += 1
        else:
            self._refuse("refused" if refusal.repeats else "invalid",
                         f"{topic.name}: {refusal.reason}")

    def _spawn(self, coro: Any) -> None:
        task = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _refuse(self, kind: str, reason: str, count: int = 1) -> None:
        self.refused[kind] += count
        self.last_refusal = reason
        now = time.monotonic()
        if now - self._logged.get(kind, -1e9) >= REFUSAL_LOG_S:
            self._logged[kind] = now
            log.warning("ros2: refused (%s): %s", kind, reason)

    # -- health ---------------------------------------------------------------------------------

    def health(self) -> Health:
        if self.node is None:
            return Health("error", "no DDS node: see the log for why it did not start",
                          self._figures())
        return Health("ok", values=self._figures())

    def _figures(self) -> dict[str, Any]:
        outlet = self.outlet
        return {
            "node": self.node_label, "domain_id": self.domain,
            "discovery": "localhost" if self.localhost else "subnet",
            "distro": self.settings.distro, "allow_commands": self.settings.allow_commands,
            "security": None if self.enclave is None else str(self.enclave.path),
            "subscribers": {name: o.matched for name, o in self.outgoing.items()},
            "published": sum(o.published for o in self.outgoing.values()),
            "dropped": (outlet.dropped if outlet else 0) + self.overflow,
            "write_errors": outlet.failed if outlet else 0,
            "accepts": sorted(self.incoming),
            "received": self.received, "accepted": self.accepted,
            "refused": dict(self.refused), "last_refusal": self.last_refusal,
            "duplicate_node": bool(self.duplicates),
        }


def _served(topic: TopicOut[Any] | TopicIn) -> bool:
    """Every incoming topic, and every outgoing one that rosbridge serves or whose type is a
    ROS 2 one (/diagnostics; not arbiterd's own /commands log)."""
    return isinstance(topic, TopicIn) or topic.bridge or not topic.type.startswith("arbiterd_")


def _user_data(ros_type: str) -> bytes:
    """The endpoint's USER_DATA: ROS 2's type hash of ``ros_type`` (REP 2011), which the
    middlewares of Iron and later read and compare."""
    return typehash.user_data(ros_type)


def _encoder(topic: TopicOut[Any]) -> Callable[[Any], bytes]:
    """Bus message -> CDR: a LaserScan straight from its arrays, the rest through the topic's
    converter and the message layer's encoder."""
    if topic.type == LASER_SCAN:
        return scan_cdr
    convert, type_name = topic.convert, topic.type
    return lambda message: cdr.encode(type_name, convert(message))


def _announcement(data: bytes, gid_size: int) -> tuple[bytes, list[announce.NodeInfo]]:
    """Another participant's announcement, in our release's layout or the other one."""
    try:
        return announce.decode(data, gid_size)
    except cdr.CdrError:
        return announce.decode(data, 40 - gid_size)


def create(ctx: DaemonContext) -> Ros2Face | None:
    """Component factory; None when ``[ros2] enabled = false``. Enabled without the binding
    is a configuration error naming the package and how to install it."""
    settings = ctx.settings(Ros2Settings)
    if not settings.enabled:
        return None
    missing = available()
    if missing is not None:
        raise ValueError(f"[ros2] enabled = true, but {missing}")
    enclave = None
    if settings.security:
        try:
            enclave = security.enclave(settings.security)
        except security.SecurityError as exc:
            raise ValueError(f"[ros2] security: {exc}") from None
    return Ros2Face(ctx, settings, enclave)


COMPONENT = ComponentSpec("ros2", create, Ros2Settings)
