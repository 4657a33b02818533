# Timed scenario scripts for `arbiterd simulate --script`: commands and events at given times.
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.commands import CommandError, Twist, parse_twist
from sim.world import finite_number, load_document

#: the actions a step can take; exactly one per step
ACTIONS = ("cmd_vel", "stop", "estop", "autonomy", "lidar", "stall", "mark")
DEFAULT_RATE_HZ = 10.0


class ScriptError(ValueError):
    """A script that cannot be run; names the step and the field."""


@dataclass(frozen=True)
class Step:
    """One timed action. ``cmd_vel`` is re-sent at ``rate`` Hz until the next ``cmd_vel`` or
    ``stop`` step (as a teleop client does); ``stop`` ends the sending (the deadman then
    brakes); ``estop`` latches/releases; ``autonomy`` sets the mode; ``lidar`` is ``stall`` or
    ``resume``; ``stall`` blocks the event loop for that many seconds (no tick, command or
    revolution is handled; the stall supervisor still runs); ``mark`` only records the
    ground truth under a label."""

    t: float
    action: str
    value: Any
    rate: float = DEFAULT_RATE_HZ
    label: str = ""


def load_script(path: str | Path) -> list[Step]:
    """Read a ``.toml`` (``[[step]]`` tables) or ``.json`` (``{"steps": [...]}`` or a list)."""
    toml = Path(path).suffix.lower() == ".toml"
    return load_document(path, "script", ScriptError,
                         lambda data: parse_steps(_steps_in(data, toml)))


def _steps_in(data: Any, toml: bool) -> Any:
    if toml:
        return data.get("step", [])
    return data.get("steps", data) if isinstance(data, dict) else data


def parse_steps(data: Any) -> list[Step]:
    if not isinstance(data, list):
        raise ScriptError("expected a list of steps")
    steps = [_step(item, f"step[{i}]") for i, item in enumerate(data)]
    for i in range(1, len(steps)):
        if steps[i].t < steps[i - 1].t:
            raise ScriptError(f"step[{i}].t: {steps[i].t} is before the previous step's "
                              f"{steps[i - 1].t}; steps must be in time order")
    return steps


def _step(item: Any, where: str) -> Step:
    if not isinstance(item, dict):
        raise ScriptError(f"{where}: expected a table/object")
    unknown = sorted(set(item) - {"t", "rate", "label", *ACTIONS})
    if unknown:
        raise ScriptError(f"{where}.{unknown[0]}: unknown field (expected t, one of "
                          f"{', '.join(ACTIONS)}, and optionally rate, label)")
    t = _number(item.get("t"), f"{where}.t")
    if t < 0:
        raise ScriptError(f"{where}.t: must be >= 0, got {t}")
    actions = [a for a in ACTIONS if a in item]
    if len(actions) != 1:
        raise ScriptError(f"{where}: expected exactly one of {', '.join(ACTIONS)}, got "
                          f"{', '.join(actions) or 'none'}")
    action = actions[0]
    rate = _number(item.get("rate", DEFAULT_RATE_HZ), f"{where}.rate")
    if not 0 < rate <= 1000:
        raise ScriptError(f"{where}.rate: must be in (0, 1000] Hz, got {rate}")
    label = item.get("label", "")
    if not isinstance(label, str):
        raise ScriptError(f"{where}.label: expected a string")
    return Step(t, action, _value(action, item[action], f"{where}.{action}"), rate,
                label or (item[action] if action == "mark" else action))


def _value(action: str, value: Any, where: str) -> Any:
    if action == "cmd_vel":
        if not isinstance(value, dict):
            raise ScriptError(f"{where}: expected a Twist-shaped table, e.g. "
                              f"{{linear = {{x = 0.5}}, angular = {{z = 0.0}}}}")
        try:
            twist: Twist = parse_twist(value)
        except CommandError as exc:
            raise ScriptError(f"{where}: {exc}") from None
        return twist
    choices = {"stop": (True,), "estop": (True, False), "autonomy": ("wander", "off"),
               "lidar": ("stall", "resume")}.get(action)
    if choices is not None and value not in choices:
        raise ScriptError(f"{where}: expected one of {', '.join(map(json.dumps, choices))}, "
                          f"got {json.dumps(value)}")
    if action == "mark" and not isinstance(value, str):
        raise ScriptError(f"{where}: expected a label string")
    if action == "stall":
        seconds = _number(value, where)
        if not 0 < seconds <= 60:
            raise ScriptError(f"{where}: expected seconds in (0, 60], got {seconds}")
        return seconds
    return value


def _number(value: Any, where: str) -> float:
    return finite_number(value, where, ScriptError)
