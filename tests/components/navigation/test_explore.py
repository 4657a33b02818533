# Frontier exploration (the autonomy's mode explore, driven by the navigation component) in
# lockstep simulated time against the true world: the apartment explored and the robot back
# at its start with no collision; teleop, a goal and the e-stop end it with the reason.
from __future__ import annotations

import json
from collections.abc import AsyncIterator

import pytest

from daemon.commands import Twist
from daemon.components.navigation.messages import GoalRequest
from daemon.config import load_config
from daemon.lockstep.explore import known_share, reachable_area
from daemon.lockstep.runner import Lockstep
from tests.support.navigation import apartment_lockstep, nav_of


@pytest.fixture
async def apartment() -> AsyncIterator[Lockstep]:
    async with apartment_lockstep() as lockstep:
        yield lockstep


def test_simulate_explore_knows_the_apartment_and_comes_back_without_a_collision(
        capsys: pytest.CaptureFixture[str]) -> None:
    from daemon.cli import main

    assert main(["simulate", "--explore", "--world", "apartment", "--seed", "1",
                 "--json"]) == 0
    (run,) = json.loads(capsys.readouterr().out)["explorations"]
    assert run["state"] == "done", run
    assert not run["capped"] and run["known_pct"] >= 95.0
    assert run["collisions"] == 0
    assert run["home_error_m"] <= 0.10
    assert run["explored_m2"] > 40.0 and run["goals"] >= 3


async def test_before_exploring_the_apartment_is_mostly_unknown(apartment: Lockstep) -> None:
    nav = nav_of(apartment)
    await apartment.advance(1.0)
    nav._look(apartment.now)  # fold the first revolutions in, as exploring does
    world = apartment.world.world
    start = (world.start.x, world.start.y, world.start.theta)
    truth = reachable_area(world, apartment.world.geometry.footprint_radius)
    assert 0.05 < known_share(nav, start, truth["robot"]) < 0.8


async def test_teleop_ends_the_exploration_and_the_mode(apartment: Lockstep) -> None:
    nav = nav_of(apartment)
    assert apartment.autonomy.request("explore", "test") is None
    await apartment.advance(3.0)
    assert nav.exploring and nav.navigator.active and apartment.world.physics.state.v > 0.05
    assert apartment.autonomy.status()["exploration"]["state"] == "exploring"
    assert nav.brief()["exploration"]["explored_m2"] > 0
    await apartment.control.submit("teleop", Twist(0.0, 0.0), t_recv=apartment.now)
    await apartment.advance(0.1)
    assert apartment.autonomy.mode == "off"
    assert nav.explorer.state == "canceled" and "teleop" in nav.explorer.reason
    assert not nav.navigator.active


async def test_a_goal_replaces_the_exploration_and_the_e_stop_fails_it(
        apartment: Lockstep) -> None:
    nav, autonomy = nav_of(apartment), apartment.autonomy
    autonomy.request("explore", "test")
    await apartment.advance(2.0)
    nav.request(GoalRequest("odom", 0.5, 0.0, None))
    await apartment.advance(0.1)
    assert nav.explorer.state == "canceled" and nav.explorer.reason == "replaced by a goal"
    assert autonomy.mode == "off" and nav.navigator.active
    nav.cancel("test")

    assert autonomy.request("explore", "test") is None
    await apartment.advance(2.0)
    await apartment.control.engage_estop("test")
    await apartment.advance(0.3)
    assert nav.explorer.state == "failed" and "e-stop" in nav.explorer.reason
    assert autonomy.mode == "off"
    assert "e-stop" in (autonomy.request("explore", "test") or "")
    apartment.control.release_estop()
    await apartment.advance(1.0)
    assert apartment.world.physics.state.v == pytest.approx(0.0, abs=1e-3)


async def test_explore_needs_the_navigation_component() -> None:
    config = load_config(None, sim=True, env={})
    config.update("sim", {"world_file": "apartment"})
    lockstep = Lockstep(config)
    refusal = lockstep.autonomy.request("explore", "test")
    assert refusal is not None and "[navigation]" in refusal
    assert lockstep.autonomy.mode == "off"
    lockstep.world.close()
