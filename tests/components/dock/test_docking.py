# Going home in lockstep on the simulated world: docked on the true dock, charging; leaving;
# the power policy sending the robot home by itself.
from __future__ import annotations

import math

from daemon.config import load_config
from daemon.lockstep.dock import DockRun
from daemon.lockstep.runner import Lockstep
from slam.pose import between


async def test_one_docking_from_across_the_room_and_back_out() -> None:
    run = DockRun("apartment", 2, 1, drift=False, mapping=False)
    (row,) = await run.run()
    assert row["docked"], row
    assert row["error_m"] <= 0.02 and row["error_deg"] <= 2.0 and row["collisions"] == 0
    assert row["distance_m"] > 0.5  # it came from somewhere else


async def test_leaving_backs_out_and_the_pack_stops_charging() -> None:
    run = DockRun("warehouse", 3, 1, drift=False, mapping=False)
    lockstep, dock = run.lockstep, run.dock
    await lockstep.begin()
    await lockstep.advance(0.3)
    nav = lockstep.navigation
    assert nav is not None
    dock.set_dock(nav.frame, between(run.start, run.true_dock))
    dock.go_home()
    await lockstep.advance(200.0, until=lambda: not dock.active)
    assert dock.docked and lockstep.world.on_charger()
    await lockstep.advance(3.0)
    assert lockstep.world.battery.measure()[1] < 0  # charging
    dock.leave()
    await lockstep.advance(30.0, until=lambda: not dock.active)
    state = lockstep.world.physics.state
    away = math.hypot(state.x - run.true_dock[0], state.y - run.true_dock[1])
    assert dock.result == "undocked" and away >= 0.35
    assert not lockstep.world.on_charger()
    assert lockstep.world.metrics_summary()["collisions"] == 0
    await lockstep.finish()


async def test_at_low_charge_it_goes_home_by_itself_once_the_goal_ends() -> None:
    config = load_config(None, sim=True, env={})
    config.update("sim", {"world_file": "apartment", "seed": 4, "battery_charge": 0.19,
                          "noise": False})
    config.update("battery", {"smoothing_s": 0.0})
    lockstep = Lockstep(config, dock=True)
    dock, nav, battery = lockstep.dock, lockstep.navigation, lockstep.battery
    assert dock is not None and nav is not None and battery is not None
    world = lockstep.world.world
    start = (world.start.x, world.start.y, world.start.theta)
    await lockstep.begin()
    await lockstep.advance(1.0)
    assert battery.level == "low"
    true = world.docks[0]
    dock.set_dock(nav.frame, between(start, (true.x, true.y, true.theta)))
    from daemon.components.navigation.messages import GoalRequest
    nav.request(GoalRequest(nav.frame, 1.0, 0.5, 0.0))
    await lockstep.advance(2.0)
    assert nav.navigator.active and not dock.active  # the task goes on
    await lockstep.advance(120.0, until=lambda: dock.active)
    assert dock.auto == "battery low" and nav.navigator.goals == 2  # its own, the second
    await lockstep.advance(200.0, until=lambda: not dock.active)
    assert dock.docked and lockstep.world.on_charger()
    await lockstep.finish()


def test_simulate_dock_and_day_refuse_bad_counts(capsys: object) -> None:
    import argparse

    from daemon.lockstep.command import EXIT_USAGE, add_parser, run
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())
    for argv in (["simulate", "--dock", "0"], ["simulate", "--day", "0"],
                 ["simulate", "--day", "100"]):
        assert run(parser.parse_args(argv)) == EXIT_USAGE
