# Autonomy: the wander FSM on synthetic sector histograms, and its component in the daemon.
from __future__ import annotations

import math
import random
import time
from collections.abc import Callable
from typing import Any

import aiohttp
import numpy as np
import pytest

from daemon.bus import Bus
from daemon.clock import VirtualClock
from daemon.commands import Twist
from daemon.component import Plugs
from daemon.components.autonomy.component import RESUME_AFTER_STALL_S, AutonomyComponent
from daemon.components.autonomy.component import STATE as AUTONOMY_STATE
from daemon.components.autonomy.sectors import Sectors
from daemon.components.autonomy.wander import Perception, Wander, WanderSettings
from daemon.components.control.loop import ControlLoop
from daemon.components.control.supervisor import StallSupervisor
from daemon.config import build_driver, load_config
from daemon.latency import LatencyTracker
from daemon.telemetry import SCAN
from sensors.scan import LaserScan
from tests.support.in_process_daemon import InProcessDaemon
from tests.support.wait import eventually

SECTORS = Sectors(48, 0.5, 2.4)
ANGLES = SECTORS.angles
SETTINGS = WanderSettings()


def seen(free: Callable[[np.ndarray], np.ndarray] | float, heading: float = 0.0,
         blocked: str | None = None, held: bool = False) -> Perception:
    """A perception whose free distance per sector is a constant or a function of angle."""
    values = np.full(len(ANGLES), float(free)) if isinstance(free, int | float) else free(ANGLES)
    return Perception(values, ANGLES, heading, blocked, held)


def wander(seed: int = 1) -> Wander:
    fsm = Wander(SETTINGS, random.Random(seed))
    fsm.start(0.0, 0.0)
    return fsm


def wall_ahead(distance: float) -> Callable[[np.ndarray], np.ndarray]:
    """Free distance of a wall across the path at ``distance``, open behind; the right side
    (negative angles) is walled in closely."""
    def free(angles: np.ndarray) -> np.ndarray:
        ahead = np.abs(angles) < math.pi / 2
        along = np.where(ahead, distance / np.maximum(np.cos(angles), 1e-3), 3.0)
        right = angles < 0
        return np.minimum(np.where(right, 0.3, along), 3.0)
    return free


# -- the sector histogram -------------------------------------------------------------------------

def test_sectors_measure_the_corridor_the_robot_needs() -> None:
    sectors = Sectors(48, half_width=0.3, look=3.0, tight_width=0.2)
    comfortable, tight = sectors.free(np.array([1.5]), np.array([0.25]))  # a post just left
    assert comfortable[0] == pytest.approx(1.5 - math.sqrt(0.3 ** 2 - 0.25 ** 2))
    assert tight[0] == pytest.approx(3.0)  # the robot itself would pass it
    assert comfortable[sectors.index(math.pi / 2)] == pytest.approx(3.0)  # nothing left
    assert comfortable[sectors.index(-math.radians(30))] == pytest.approx(3.0)  # clear right


# -- the FSM -----------------------------------------------------------------------------------

def test_cruises_in_the_open() -> None:
    fsm = wander()
    v, w = fsm.decide(0.1, seen(3.0))
    assert fsm.state == "CRUISE" and 0.0 < v <= SETTINGS.cruise_speed
    assert abs(w) <= SETTINGS.turn_speed  # toward its (random) wander heading


def test_avoids_then_turns_in_place_then_cruises_again() -> None:
    fsm = wander()
    v, w = fsm.decide(0.1, seen(wall_ahead(1.2)))
    assert fsm.state == "AVOID" and 0 < v < SETTINGS.cruise_speed and w > 0  # toward the room
    v, w = fsm.decide(0.2, seen(wall_ahead(0.3)))
    assert fsm.state == "ROTATE" and v == 0.0 and w != 0.0
    side = math.copysign(1.0, w)
    heading = 0.0
    for step in range(100):
        heading += side * 0.1
        open_ahead = seen(lambda a, h=heading: wall_ahead(0.3)(a + h), heading)
        v, w = fsm.decide(0.3 + step * 0.1, open_ahead)
        if fsm.state != "ROTATE":
            break
        assert math.copysign(1.0, w) == side  # committed to one direction, no dithering
    assert fsm.state == "CRUISE"


def test_boxed_in_backs_up_then_turns() -> None:
    fsm = wander()
    fsm.decide(0.1, seen(wall_ahead(0.3)))
    v, w = fsm.decide(0.2, seen(0.3))  # nothing has room to drive
    assert fsm.state == "BACKUP" and v < 0 and w == 0.0
    t = 0.3
    while fsm.state == "BACKUP":
        fsm.decide(t, seen(0.3))
        t += 0.1
    assert fsm.state == "ROTATE" and t - 0.2 == pytest.approx(SETTINGS.backup_s, abs=0.15)


def test_repeated_turns_in_a_corner_trigger_a_back_up() -> None:
    fsm = wander()
    t = 0.0
    states = []
    for _ in range(SETTINGS.traps):
        t += 0.1
        fsm.decide(t, seen(wall_ahead(0.3)))  # blocked: ROTATE
        states.append(fsm.state)
        t += 0.1
        fsm._go("CRUISE", t, "test: pretend it turned away")
    assert states[:-1] == ["ROTATE"] * (SETTINGS.traps - 1) and states[-1] == "BACKUP"


def test_stopped_while_blocked_and_back_to_cruise_after() -> None:
    fsm = wander()
    assert fsm.decide(0.1, seen(3.0, blocked="no fresh lidar scan")) == (0.0, 0.0)
    assert fsm.state == "STOPPED" and fsm.reason == "no fresh lidar scan"
    fsm.decide(0.2, seen(3.0))
    assert fsm.state == "CRUISE"
    assert fsm.transitions == 3  # CRUISE, STOPPED, CRUISE


def test_time_in_each_state_adds_up() -> None:
    fsm = wander()
    for step in range(1, 31):
        fsm.decide(step * 0.1, seen(wall_ahead(0.3) if step > 20 else 3.0))
    assert sum(fsm.time_in.values()) == pytest.approx(3.0)
    assert fsm.time_in["CRUISE"] == pytest.approx(2.0, abs=0.15)


def test_same_seed_same_decisions() -> None:
    def run(seed: int) -> list[tuple[float, float]]:
        fsm = wander(seed)
        return [fsm.decide(t * 0.1, seen(lambda a, t=t: 1.5 + np.sin(a * 3 + t))) for t in
                range(1, 300)]
    assert run(7) == run(7)
    assert run(7) != run(8)


# -- the component in the daemon (in-process robot, emulated lidar) ------------------------------

async def request(robot: InProcessDaemon, method: str, path: str,
                  body: Any = None) -> tuple[int, dict[str, Any]]:
    async with aiohttp.ClientSession() as session, session.request(
            method, robot.http_url + path, json=body) as response:
        return response.status, await response.json()


async def test_autonomy_api_wander_and_teleop_override(robot: InProcessDaemon) -> None:
    status, body = await request(robot, "GET", "/api/autonomy")
    assert status == 200 and (body["mode"], body["state"]) == ("off", "IDLE")
    status, body = await request(robot, "POST", "/api/autonomy", {"mode": "wander"})
    assert status == 200 and body["mode"] == "wander"
    await eventually(robot.moving, "the wander behaviour to drive")
    status, body = await request(robot, "GET", "/api/autonomy")
    assert body["state"] in ("CRUISE", "AVOID", "ROTATE") and body["transitions"] >= 1
    assert body["time_in_state_s"] >= 0.0 and "state_times_s" in body
    control = robot.control
    await control.submit("http", Twist(0.0, 0.0), t_recv=time.monotonic())  # a teleop says stop
    status, body = await request(robot, "GET", "/api/autonomy")
    assert (body["mode"], body["state"]) == ("off", "IDLE") and "teleop" in body["reason"]
    await eventually(lambda: not robot.moving(), "the robot to stop")


async def test_autonomy_api_refuses_bad_requests(robot: InProcessDaemon) -> None:
    assert (await request(robot, "POST", "/api/autonomy", {"mode": "dance"}))[0] == 422
    assert (await request(robot, "POST", "/api/autonomy", {"mode": "off", "x": 1}))[0] == 422
    await robot.control.engage_estop("test")
    status, body = await request(robot, "POST", "/api/autonomy", {"mode": "wander"})
    assert status == 409 and "e-stop" in body["error"]


async def test_estop_stops_wander_and_it_waits_to_be_asked_again(robot: InProcessDaemon) -> None:
    assert (await request(robot, "POST", "/api/autonomy", {"mode": "wander"}))[0] == 200
    await eventually(robot.moving, "the wander behaviour to drive")
    control = robot.control
    await control.engage_estop("test")
    await eventually(lambda: robot.component("autonomy").wander.state == "STOPPED",
                     "the behaviour to stop")
    assert not robot.moving()
    control.release_estop()
    await eventually(lambda: robot.component("autonomy").mode == "off",
                     "the behaviour to switch off after the e-stop")
    assert not robot.moving()


async def test_autonomy_state_is_published_on_change(robot: InProcessDaemon) -> None:
    states: list[dict[str, Any]] = []
    robot.ctx.bus.subscribe(AUTONOMY_STATE, states.append)
    await request(robot, "POST", "/api/autonomy", {"mode": "wander"})
    await eventually(lambda: any(s["state"] == "CRUISE" for s in states), "a CRUISE state")
    await request(robot, "POST", "/api/autonomy", {"mode": "off"})
    assert states[-1]["mode"] == "off"


# -- a stall stop holds wander still; it goes on by itself (lockstep: simulated time) ------------

class SteppedWander:
    """The control loop and the autonomy on a virtual clock, ticked by hand, with the stall
    supervisor on the same clock and an open room on the bus every 0.1 s."""

    def __init__(self) -> None:
        config = load_config(None, env={})
        config.update("driver", {"type": "mock"})
        self.clock = VirtualClock()
        self.bus = Bus()
        self.driver = build_driver(config, "mock")
        self.control = ControlLoop(config, self.driver, self.bus, LatencyTracker(),
                                   clock=self.clock)
        self.control.supervisor = StallSupervisor(self.driver, 0.2, clock=self.clock)
        plugs = Plugs(self.control, self.control, self.bus)
        self.autonomy = AutonomyComponent(config, plugs, lidar=True, seed=1)
        self.t = 0.0
        self._next_scan = 0.0

    def open_room(self) -> LaserScan:
        rays = 360
        return LaserScan(0.0, "laser", -math.pi, math.pi, 2 * math.pi / rays, 0.0, 0.1, 0.1,
                         12.0, np.full(rays, 5.0, dtype=np.float32),
                         np.zeros(rays, dtype=np.float32))

    async def run(self, seconds: float) -> None:
        """Tick on time (each tick pets the supervisor, as the real tick does)."""
        period = self.control.period_s
        for _ in range(round(seconds / period)):
            self.t += period
            self.clock.set(self.t)
            if self.t >= self._next_scan:
                self.bus.publish(SCAN, self.open_room())
                self._next_scan = self.t + 0.1
            self.control.supervisor.beat()
            await self.control.tick(self.t)

    def stall(self, seconds: float) -> None:
        """The event loop blocked for ``seconds``: no tick; the supervisor's thread looks."""
        self.t += seconds
        self.clock.set(self.t)
        self.control.supervisor.check()

    def moving(self) -> bool:
        return self.driver.last_command != (0.0, 0.0)


async def test_wander_stopped_only_by_a_stall_goes_on_once_the_tick_is_healthy() -> None:
    robot = SteppedWander()
    await robot.control.start(realtime=False)
    try:
        robot.autonomy.set_mode("wander", "test")
        await robot.run(1.0)
        assert robot.moving() and robot.autonomy.wander.state == "CRUISE"

        robot.stall(0.3)
        assert robot.control.supervisor.stall_stops == 1 and not robot.moving()

        await robot.run(1.0)  # the tick is back: the behaviour holds still, still in wander
        assert robot.autonomy.mode == "wander" and not robot.moving()
        assert robot.autonomy.wander.state == "STOPPED"
        assert "stall" in robot.autonomy.wander.reason

        robot.stall(0.3)  # another stall during the wait: the wait starts over
        await robot.run(RESUME_AFTER_STALL_S - 0.2)
        assert robot.autonomy.mode == "wander" and not robot.moving()

        await robot.run(0.5)  # healthy for longer than RESUME_AFTER_STALL_S: it goes on
        assert robot.autonomy.mode == "wander" and robot.moving()
        assert robot.autonomy.wander.state == "CRUISE"
        assert robot.control.supervisor.stall_stops == 2
    finally:
        await robot.control.stop()


async def test_after_a_stall_and_an_estop_wander_waits_to_be_asked_again() -> None:
    robot = SteppedWander()
    await robot.control.start(realtime=False)
    try:
        robot.autonomy.set_mode("wander", "test")
        await robot.run(1.0)
        robot.stall(0.3)
        await robot.run(0.2)
        await robot.control.engage_estop("test")
        robot.control.release_estop()
        await robot.run(RESUME_AFTER_STALL_S + 0.5)
        assert robot.autonomy.mode == "off" and not robot.moving()
    finally:
        await robot.control.stop()
