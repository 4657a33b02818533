# rosapi discovery services answered from the daemon's own topic/service graph (no ROS).
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Protocol

from daemon.messages.msgtypes import MessageError, full_text, normalize_type, stamp

ROS_DISTRO = "arbiterd"


class ServiceError(Exception):
    """A service call that failed; the text goes back as ``values`` with ``result: false``."""


class Graph(Protocol):
    """The view of topics, services and nodes that rosapi reports."""

    def topic_types(self) -> dict[str, str]: ...

    def publishers(self, topic: str) -> list[str]: ...

    def subscribers(self, topic: str) -> list[str]: ...

    def service_types(self) -> dict[str, str]: ...

    def node_names(self) -> list[str]: ...

    def node_details(self, node: str) -> tuple[list[str], list[str], list[str]]: ...


Handler = Callable[[Graph, dict[str, str]], dict[str, Any]]


def _topics(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    types = graph.topic_types()
    return {"topics": list(types), "types": list(types.values())}


def _topics_and_raw_types(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    types = graph.topic_types()
    return {"topics": list(types), "types": list(types.values()),
            "typedefs_full_text": [full_text(t) for t in types.values()]}


def _topic_type(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    return {"type": graph.topic_types().get(_slash(args["topic"]), "")}


def _topics_for_type(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    try:
        wanted = normalize_type(args["type"])
    except MessageError as exc:
        raise ServiceError(str(exc)) from None
    return {"topics": [t for t, ty in graph.topic_types().items() if ty == wanted]}


def _services(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    return {"services": list(graph.service_types())}


def _services_for_type(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    try:
        wanted = normalize_type(args["type"], "srv")
    except MessageError as exc:
        raise ServiceError(str(exc)) from None
    return {"services": [s for s, ty in graph.service_types().items() if ty == wanted]}


def _service_type(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    return {"type": graph.service_types().get(_slash(args["service"]), "")}


def _nodes(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    return {"nodes": graph.node_names()}


def _node_details(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    node = _slash(args["node"])
    if node not in graph.node_names():
        raise ServiceError(f"node {args['node']!r} does not exist")
    subscribing, publishing, services = graph.node_details(node)
    return {"subscribing": subscribing, "publishing": publishing, "services": services}


def _publishers(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    return {"publishers": graph.publishers(_slash(args["topic"]))}


def _subscribers(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    return {"subscribers": graph.subscribers(_slash(args["topic"]))}


def _get_time(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    return {"time": stamp(time.time())}


def _get_ros_version(graph: Graph, args: dict[str, str]) -> dict[str, Any]:
    return {"version": 2, "distro": ROS_DISTRO}


def _slash(name: str) -> str:
    return name if name.startswith("/") else "/" + name


# service => (type, request fields (all strings), handler)
SERVICES: dict[str, tuple[str, tuple[str, ...], Handler]] = {
    "/rosapi/topics": ("rosapi_msgs/srv/Topics", (), _topics),
    "/rosapi/topics_and_raw_types": ("rosapi_msgs/srv/TopicsAndRawTypes", (),
                                     _topics_and_raw_types),
    "/rosapi/topic_type": ("rosapi_msgs/srv/TopicType", ("topic",), _topic_type),
    "/rosapi/topics_for_type": ("rosapi_msgs/srv/TopicsForType", ("type",), _topics_for_type),
    "/rosapi/services": ("rosapi_msgs/srv/Services", (), _services),
    "/rosapi/services_for_type": ("rosapi_msgs/srv/ServicesForType", ("type",),
                                  _services_for_type),
    "/rosapi/service_type": ("rosapi_msgs/srv/ServiceType", ("service",), _service_type),
    "/rosapi/nodes": ("rosapi_msgs/srv/Nodes", (), _nodes),
    "/rosapi/node_details": ("rosapi_msgs/srv/NodeDetails", ("node",), _node_details),
    "/rosapi/publishers": ("rosapi_msgs/srv/Publishers", ("topic",), _publishers),
    "/rosapi/subscribers": ("rosapi_msgs/srv/Subscribers", ("topic",), _subscribers),
    "/rosapi/get_time": ("rosapi_msgs/srv/GetTime", (), _get_time),
    "/rosapi/get_ros_version": ("rosapi_msgs/srv/GetROSVersion", (), _get_ros_version),
}


def request_args(service: str, args: Any) -> dict[str, str]:
    """``args`` (object, list zipped onto the request fields, or absent) checked as strings."""
    fields = SERVICES[service][1]
    if args is None:
        args = {}
    elif isinstance(args, list):
        if len(args) > len(fields):
            raise ServiceError(f"{service} takes {len(fields)} argument(s), got {len(args)}")
        args = dict(zip(fields, args, strict=False))
    if not isinstance(args, dict):
        raise ServiceError(f"args: expected an object or a list, got {type(args).__name__}")
    unknown = sorted(set(args) - set(fields))
    if unknown:
        raise ServiceError(f"{service} request does not have a field {unknown[0]!r}")
    for key, value in args.items():
        if not isinstance(value, str):
            raise ServiceError(f"{service} request field {key!r}: expected a string")
    return {key: args.get(key, "") for key in fields}


def call(graph: Graph, service: str, args: Any) -> dict[str, Any]:
    """Answer one rosapi call (``service`` already canonical, with the leading slash)."""
    return SERVICES[service][2](graph, request_args(service, args))
