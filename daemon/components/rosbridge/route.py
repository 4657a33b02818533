# A client's publish path to one robot topic, precompiled once the general path has let it through.
from __future__ import annotations

from collections.abc import Callable
from typing import Any

from daemon.components.rosbridge.codec import ProtocolError
from daemon.components.rosbridge.graph import Topic
from daemon.coords import missing_required
from daemon.messages.definitions import STRING
from daemon.messages.msgtypes import MessageError, check_message
from daemon.topics import Access, InboundHandler, TopicIn

#: most routes one client keeps (robot topics are few; spellings of them are bounded too)
MAX_ROUTES = 16

FastCheck = Callable[[Any], dict[str, Any] | None]


def _string(raw: Any) -> dict[str, Any] | None:
    """std_msgs/String in the shape :func:`check_message` returns unchanged, else None."""
    if type(raw) is dict and len(raw) == 1 and type(raw.get("data")) is str:
        return raw
    return None


#: type -> a check of the common shape that gives what check_message gives (None: ask it)
FAST_CHECKS: dict[str, FastCheck] = {STRING: _string}


class Route:
    """What a ``publish`` to one of the robot's incoming topics needs after the general path
    checked one from this client: the topic the access check found, the access it declares,
    the type this client advertised for it and the message check of that type. Only for
    topics whose access does not depend on the message (not the e-stop's)."""

    __slots__ = ("access", "fast", "handler", "name", "required", "topic", "type_name")

    def __init__(self, topic: Topic, robot: TopicIn, type_name: str) -> None:
        self.name = topic.name
        self.topic = topic
        self.access: Access = robot.access
        self.handler: InboundHandler = robot.handler
        self.type_name = type_name
        self.fast = FAST_CHECKS.get(type_name)
        self.required = robot.required

    def check(self, raw: Any) -> dict[str, Any]:
        """The message checked as ``op_publish`` checks it: the same result, the same error."""
        fast = self.fast
        msg = fast(raw) if fast is not None else None
        if msg is not None:
            return msg
        try:
            checked = check_message(self.type_name, raw)
        except MessageError as exc:
            raise ProtocolError(f"publish {self.name}: {exc}") from None
        missing = missing_required(raw, self.required) if self.required else None
        if missing is not None:
            raise ProtocolError(f"publish {self.name}: msg.{missing}")
        return checked


def usable(robot: object) -> bool:
    """Whether publishing to a robot topic may take a route: an incoming topic whose access
    is the same for every message."""
    return isinstance(robot, TopicIn) and robot.access_for is None


def fast_frame(payload: Any) -> str | None:
    """The topic spelling of a ``publish`` frame a route may take (no ``type``, an ``id``
    that :func:`~daemon.components.rosbridge.codec.check_frame` accepts), else None."""
    if type(payload) is not dict or payload.get("op") != "publish" or "type" in payload:
        return None
    rid = payload.get("id")
    if rid is not None and type(rid) is not str and type(rid) is not int:
        return None
    topic = payload.get("topic")
    return topic if type(topic) is str else None
