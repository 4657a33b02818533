# A component's health as one typed value: a status, the one problem that explains it, values.
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

Status = Literal["ok", "degraded", "error"]

#: Health statuses, from best to worst.
STATUSES: tuple[Status, ...] = ("ok", "degraded", "error")
#: keys every rendering of a health value owns
RESERVED = frozenset({"status", "problem"})


@dataclass(frozen=True)
class Health:
    """What ``Component.health()`` returns. ``problem`` is the one line that says why the
    status is not ``ok`` (or what an ``ok`` component cannot do); ``values`` are the figures
    shown beside it. Every transport renders it through :meth:`to_json`: ``/api/health``,
    ``arbiterd status``, ``/diagnostics`` and the console read the same ``problem``."""

    status: Status
    problem: str = ""
    values: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"health status must be one of {STATUSES}, got {self.status!r}")
        if self.status != "ok" and not self.problem:
            raise ValueError(f"a health status {self.status!r} needs a problem saying why")
        clash = RESERVED & set(self.values)
        if clash:
            raise ValueError(f"health values may not use the keys {sorted(clash)}")

    @classmethod
    def of(cls, report: Mapping[str, Any], *reasons: str, otherwise: str = "") -> Health:
        """A health value from a device's report dict (``{"status": ..., ...}``): the first
        non-empty of the ``reasons`` keys is the problem (``otherwise`` when none is); every
        other key is a value."""
        status = report.get("status", "error")
        problem = next((str(report[key]) for key in reasons if report.get(key)), "")
        if status != "ok" and not problem:
            problem = otherwise or f"status {status}"
        values = {k: v for k, v in report.items() if k not in RESERVED}
        return cls(status, problem, values)

    def to_json(self) -> dict[str, Any]:
        return {"status": self.status, "problem": self.problem or None, **self.values}


def worst(statuses: list[str]) -> str:
    """The worst of several health statuses (``ok`` when empty)."""
    return max(statuses, key=STATUSES.index, default="ok")


def problem_of(rendered: Mapping[str, Any]) -> str:
    """The problem of a rendered health value (``to_json``), empty when there is none."""
    return str(rendered.get("problem") or "")
