# The reaction budget in lockstep: 2 m/s at thin posts, slow and fast motors, a stalled loop.
from __future__ import annotations

import asyncio
import logging
from typing import Any

import pytest

from daemon.config import load_config
from daemon.lockstep.runner import Lockstep
from daemon.lockstep.script import parse_steps
from tests.support.paths import REPO

SCENARIOS = REPO / "tests" / "scenarios"
SLOW, FAST = 0.25, 0.05  # motor time constants, s: a hobby gear motor, the simulated default
SECONDS = 6.0  # it has stopped by 5.5 s
#: stalls begin when braking must begin, 1 s later (slow, near the post: the worst case) and 2 s
STALL_STARTS = (0.0, 1.0, 2.0)
STALL_S = 1.0  # far longer than stall_stop_s: the supervisor has to stop the wheels


def drive(post: str, motor: float, reaction: float | None = None,
          stall_at: float | None = None) -> dict[str, Any]:
    """A teleop holding 2 m/s at the post; the run's report."""
    config = load_config(None, sim=True, env={})
    config.update("sim", {"world_file": str(SCENARIOS / f"{post}.toml"),
                          "motor_time_constant": motor})
    if reaction is not None:
        config.update("collision_monitor", {"reaction_time_s": reaction})
    steps: list[dict[str, Any]] = [{"t": 0.0, "cmd_vel": {"linear": {"x": 2.0}}}]
    if stall_at is not None:
        steps.append({"t": stall_at, "stall": STALL_S})
    logging.getLogger("arbiterd").setLevel(logging.CRITICAL)
    try:
        return asyncio.run(Lockstep(config, script=parse_steps(steps)).run(SECONDS))
    finally:
        logging.getLogger("arbiterd").setLevel(logging.NOTSET)


@pytest.mark.parametrize("post", ["post_2cm", "post_4cm"])
@pytest.mark.parametrize("motor", [SLOW, FAST])
def test_full_speed_at_a_thin_post_never_touches_it(post: str, motor: float) -> None:
    calm = drive(post, motor)
    assert calm["collisions"] == 0 and calm["min_clearance_m"] > 0.05, calm["min_clearance_m"]
    assert calm["max_speed_m_s"] > 1.9  # it was going full speed when it saw the post
    brake = calm["safety"]["first_brake_s"]
    assert brake is not None
    for offset in STALL_STARTS:  # the event loop stops just as braking must begin, or later
        run = drive(post, motor, stall_at=round(brake + offset, 4))
        assert run["safety"]["stall_stops"] == 1  # the supervisor, not the loop, stopped it
        assert run["collisions"] == 0, (offset, run["min_clearance_m"])
        assert run["min_clearance_m"] > 0.05, (offset, run["min_clearance_m"])


def test_a_budget_below_the_rule_hits_the_post() -> None:
    """The same drive with slow motors and the old budget (0.1 s, below their 0.25 s time
    constant): the rule in docs/safety.md is what keeps the robot off the post."""
    run = drive("post_2cm", SLOW, reaction=0.1)
    assert run["collisions"] >= 1


def stop_from_one_metre_per_second(motor: float, reaction: float) -> dict[str, Any]:
    """Drive at 1 m/s, let go (the deadman brakes); the collision monitor's health."""
    config = load_config(None, sim=True, env={})
    config.update("sim", {"world_file": str(SCENARIOS / "post_2cm.toml"),
                          "motor_time_constant": motor})
    config.update("collision_monitor", {"reaction_time_s": reaction})
    runner = Lockstep(config, script=parse_steps([
        {"t": 0.0, "cmd_vel": {"linear": {"x": 1.0}}}, {"t": 1.5, "stop": True}]))
    asyncio.run(runner.run(5.0))
    assert runner.safety is not None
    return runner.safety.health().to_json()


def test_health_says_when_the_robot_brakes_slower_than_assumed() -> None:
    slow = stop_from_one_metre_per_second(SLOW, reaction=0.1)
    assert slow["status"] == "degraded" and "brakes slower" in slow["problem"], slow
    braking = slow["braking"]
    assert braking["measured"] and braking["stops"] == braking["slower_than_assumed"] == 1
    assert braking["last"]["lag_s"] > 0.2  # the 0.25 s motor, measured by the encoders
    assert braking["last"]["stopped_in_m"] > braking["last"]["planned_m"]

    fine = stop_from_one_metre_per_second(SLOW, reaction=0.3)
    assert fine["status"] == "ok" and fine["braking"]["stops"] == 1, fine
    assert fine["braking"]["slower_than_assumed"] == 0
