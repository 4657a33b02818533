# Missions: a short sequence of goals run one after another, with a result per step.
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from daemon.components.navigation.messages import GoalError, GoalRequest, goal_of_json

#: the most steps one mission may have
MAX_STEPS = 100
#: a step's outcome once it ended; "skipped" for the steps after a failed or canceled one
ENDED = ("succeeded", "failed", "canceled")


@dataclass
class StepResult:
    state: str = "pending"  # pending, running, succeeded, failed, canceled, skipped
    reason: str = ""
    started: float | None = None
    ended: float | None = None

    def report(self) -> dict[str, Any]:
        out: dict[str, Any] = {"state": self.state}
        if self.reason:
            out["reason"] = self.reason
        if self.started is not None and self.ended is not None:
            out["elapsed_s"] = round(self.ended - self.started, 2)
        return out


@dataclass
class Mission:
    """The steps (checked goal requests), which one runs (its goal's number) and each result."""

    name: str
    steps: list[GoalRequest]
    results: list[StepResult] = field(default_factory=list)
    index: int = 0
    goal_number: int | None = None  # the navigator's number of the running step's goal
    state: str = "running"  # running, succeeded, failed, canceled
    reason: str = ""

    def __post_init__(self) -> None:
        self.results = [StepResult() for _ in self.steps]

    @property
    def running(self) -> bool:
        return self.state == "running"

    def step_started(self, goal_number: int, now: float) -> None:
        self.goal_number = goal_number
        result = self.results[self.index]
        result.state, result.started = "running", now

    def step_ended(self, state: str, reason: str, now: float) -> bool:
        """The running step ended ``state``; True when the mission goes on to a next step."""
        result = self.results[self.index]
        result.state, result.reason, result.ended = state, reason, now
        self.goal_number = None
        if state == "succeeded" and self.index + 1 < len(self.steps):
            self.index += 1
            return True
        self.finish(state, "" if state == "succeeded" else f"step {self.index + 1}: {reason}")
        return False

    def finish(self, state: str, reason: str) -> None:
        """End the mission; the steps not run are skipped."""
        self.state, self.reason = state, reason
        for result in self.results:
            if result.state == "pending":
                result.state = "skipped"
            elif result.state == "running":
                result.state, result.reason = state, reason

    def report(self) -> dict[str, Any]:
        return {"name": self.name, "state": self.state, "reason": self.reason,
                "step": self.index + 1, "steps": len(self.steps),
                "results": [r.report() for r in self.results]}


def mission_of_json(body: dict[str, Any], default_frame: str) -> Mission:
    """``{"name"?: str, "steps": [goal, ...]}``, each goal what ``POST /api/goal`` takes; a
    GoalError names the step and field at fault."""
    unknown = sorted(set(body) - {"name", "steps"})
    if unknown:
        raise GoalError(f"{unknown[0]}: unknown field (name, steps)")
    name = body.get("name", "mission")
    if not isinstance(name, str) or not 0 < len(name) <= 64:
        raise GoalError("name: expected a string of 1..64 characters")
    raw = body.get("steps")
    if not isinstance(raw, list) or not 0 < len(raw) <= MAX_STEPS:
        raise GoalError(f"steps: expected a list of 1..{MAX_STEPS} goals")
    steps = []
    for i, step in enumerate(raw):
        if not isinstance(step, dict):
            raise GoalError(f"steps[{i}]: expected a goal object like POST /api/goal's")
        try:
            steps.append(goal_of_json(step, default_frame))
        except GoalError as exc:
            raise GoalError(f"steps[{i}].{exc}") from None
    return Mission(name, steps)
