# The component contract every part of the running daemon follows.
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:
    from daemon.bus import Bus
    from daemon.config import Config
    from daemon.control.loop import ControlLoop
    from daemon.http_api import HttpServer
    from daemon.latency import LatencyTracker
    from daemon.security import Security

#: Health statuses, from best to worst.
STATUSES = ("ok", "degraded", "error")


@runtime_checkable
class Component(Protocol):
    """A part of the daemon with a lifecycle and a health report.

    ``core`` components must start for the daemon to become ready (``READY=1``); a failing
    non-core component only degrades health. ``health()`` returns a dict whose ``"status"`` is
    one of :data:`STATUSES`; the rest is component-specific and shown in ``/api/health``.
    """

    name: str
    core: bool

    async def start(self) -> None: ...

    async def stop(self) -> None: ...

    def health(self) -> dict[str, Any]: ...


def worst(statuses: list[str]) -> str:
    """The worst of several health statuses (``ok`` when empty)."""
    return max(statuses, key=STATUSES.index, default="ok")


@dataclass
class DaemonContext:
    """What components get to build themselves and plug into the daemon."""

    config: Config
    bus: Bus
    http: HttpServer
    control: ControlLoop
    security: Security
    latency: LatencyTracker
    mode: str
    robot_info: dict[str, Callable[[], Any]] = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)
