# The component contract every part of the running daemon follows.
from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

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
