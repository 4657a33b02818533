# ROS 2 over DDS naming and discovery choices: topic and type names, domain, Cyclone's config.
from __future__ import annotations

import os
from collections.abc import Mapping

#: ROS 2's environment variables for the domain and the discovery range
DOMAIN_ENV = "ROS_DOMAIN_ID"
RANGE_ENV = "ROS_AUTOMATIC_DISCOVERY_RANGE"
LOCALHOST_ENV = "ROS_LOCALHOST_ONLY"


def dds_topic(namespace: str, name: str) -> str:
    """The DDS topic of ROS topic ``name`` under the node's namespace (``rt/robot1/scan``)."""
    return "rt" + namespace.rstrip("/") + name


def dds_type(ros_type: str) -> str:
    """``pkg/msg/Type`` -> ``pkg::msg::dds_::Type_``, as the ROS 2 middlewares name types."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def domain_id(configured: int, env: Mapping[str, str] = os.environ) -> int:
    """The configured domain, or ROS_DOMAIN_ID's when it is -1 (0 when that is unset)."""
    if configured >= 0:
        return configured
    text = env.get(DOMAIN_ENV, "").strip()
    if not text:
        return 0
    if not text.isdigit() or int(text) > 232:
        raise ValueError(f"{DOMAIN_ENV}={text!r} is not a domain id (0..232)")
    return int(text)


def localhost_only(discovery: str, env: Mapping[str, str] = os.environ) -> bool:
    """Whether discovery stays on this machine: ``localhost``, or ``auto`` with ROS 2's own
    variables saying so (the range LOCALHOST, or the older ROS_LOCALHOST_ONLY=1)."""
    if discovery != "auto":
        return discovery == "localhost"
    wanted = env.get(RANGE_ENV, "").strip().upper()
    if wanted:
        return wanted == "LOCALHOST"
    return env.get(LOCALHOST_ENV, "").strip() == "1"


def cyclone_config(localhost: bool, security: str = "") -> str:
    """Cyclone DDS's configuration: loopback only (the interface ``lo``, no multicast, a
    unicast peer 127.0.0.1 probed over automatic participant indices), else its defaults;
    ``security`` is a <Security> element (security.py) or ''."""
    if not localhost:
        return f"<CycloneDDS><Domain id='any'>{security}</Domain></CycloneDDS>"
    return ("<CycloneDDS><Domain id='any'>" + security +
            "<General><Interfaces><NetworkInterface name='lo'/></Interfaces>"
            "<AllowMulticast>false</AllowMulticast></General>"
            "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
            "<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
            "<Peers><Peer address='127.0.0.1'/></Peers></Discovery>"
            "</Domain></CycloneDDS>")
