# The "navigation" component: goals and paths, planned on a lidar costmap, as a command source.
from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np
from aiohttp import web

from base.config import Config
from daemon.bus import BusKey
from daemon.commands import Twist
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Plugs, Route
from daemon.components.collision_monitor.settings import CollisionMonitorSettings
from daemon.components.mapping.settings import MappingSettings
from daemon.components.navigation.explore import Explorer, ExploreSettings, Go
from daemon.components.navigation.messages import (
    GoalError,
    GoalRequest,
    PlanMessage,
    goal_of_json,
    goal_of_pose_stamped,
    path_msg,
)
from daemon.components.navigation.mission import Mission, mission_of_json
from daemon.components.navigation.navigator import Navigator, NavigatorSettings, Target
from daemon.components.navigation.planning import (
    Looked,
    Planned,
    PlanningWorker,
    fold,
    fold_and_look,
    fold_and_plan,
)
from daemon.components.navigation.settings import NavigationSettings
from daemon.health import Health
from daemon.messages.convert import json_string_msg
from daemon.messages.definitions import PATH, POINT_STAMPED, POSE_STAMPED, STRING
from daemon.robot import scan_points
from daemon.settings import LimitsSettings, RobotSettings
from daemon.state_publisher import StatePublisher
from daemon.telemetry import SCAN, TRANSFORMS, Transform
from daemon.topics import Inbound, Refusal, Topic, TopicIn, TopicOut
from daemon.web import ApiError, json_response, read_json_object
from daemon.workers import WorkerDown
from nav.costmap import Costmap, CostParams, GridArea, centred_area
from nav.pursuit import PursuitSettings, figure_eight, transform
from sensors.rplidar.settings import LidarSettings
from sensors.scan import LaserScan, ScanPoints
from slam.pose import Pose2, compose

T = TypeVar("T")
log = logging.getLogger("arbiterd.navigation")

SOURCE = "navigation"
PRIORITY = 1  # below every client, above the wander behaviour
#: the state on every change and once a second
STATE: BusKey[dict[str, Any]] = BusKey("navigation_state")
#: the path being followed, on every new plan
PLAN: BusKey[PlanMessage] = BusKey("navigation_plan")
#: a scan older than this holds the robot (s)
SCAN_TIMEOUT_S = 0.5
#: revolutions kept for the next plan; older ones are dropped
SCAN_QUEUE = 10
#: odometry poses kept to place a revolution at its own time (s)
HISTORY_S = 1.0
#: a goal whose cell the lidar never saw while the robot was this near it (m) for
#: UNSEEN_FAIL_S fails: it lies inside an obstacle or a closed room
UNSEEN_NEAR_M = 5.0
UNSEEN_FAIL_S = 10.0
#: ... and only once the robot has stopped getting nearer it: it has not come UNSEEN_GAIN_M
#: nearer for UNSEEN_STILL_S (a goal straight down a long aisle stays unseen while the robot
#: drives to it: the rays along the aisle have no return to clear the cells with)
UNSEEN_GAIN_M = 0.1
UNSEEN_STILL_S = 2.0
#: goal failures that are the robot's, not the goal's: they end an exploration
ROBOT_PROBLEMS = ("e-stop", "driver fault", "no fresh lidar scan", "the planner failed")


def navigator_settings(config: Config) -> NavigatorSettings:
    """The follower's limits: [navigation] speeds capped by [limits]."""
    s, limits = config.get(NavigationSettings), config.get(LimitsSettings)
    pursuit = PursuitSettings(
        max_speed=min(s.max_speed, limits.linear_x_max_velocity),
        max_turn=min(s.max_turn, limits.angular_z_max_velocity),
        max_deceleration=0.5 * limits.linear_x_max_deceleration,
        xy_tolerance=s.xy_tolerance, yaw_tolerance=s.yaw_tolerance)
    return NavigatorSettings(pursuit, s.replan_period_s, s.progress_timeout_s,
                             s.held_timeout_s, s.goal_timeout_s)


def cost_params(config: Config) -> CostParams:
    s = config.get(NavigationSettings)
    reach = footprint_reach(config.get(CollisionMonitorSettings))
    return CostParams(radius_m=reach + s.clearance_m, inflation_m=s.inflation_m,
                      unknown_cost=s.unknown_cost)


def footprint_reach(cm: CollisionMonitorSettings) -> float:
    """How far the footprint reaches from the robot's centre (m)."""
    if cm.footprint:
        return max(math.hypot(x, y) for x, y in cm.footprint)
    return float(cm.footprint_radius)


class NavigationComponent(BaseComponent):
    """Plans to a goal on a costmap of the lidar's revolutions (in the map frame while mapping
    runs, else in the odometry frame) and
    follows the plan with Regulated Pure Pursuit; its commands go through the arbiter (above
    the wander behaviour, below every client), so the collision monitor and the limiter
    apply. Any client command cancels the goal; the e-stop or a driver fault fail it; a stale
    scan holds the robot. Plans run in a worker process (``inline``: in the tick, repeatable)."""

    name = "navigation"
    core = False

    def __init__(self, config: Config, plugs: Plugs, *, lidar: bool,
                 points: ScanPoints | None = None, inline: bool = False,
                 wall_clock: Callable[[], float] = time.time) -> None:
        self.settings = settings = config.get(NavigationSettings)
        self.robot = control = plugs.robot
        self.bus = plugs.bus
        self.clock = control.clock
        self.wall_clock = wall_clock
        self.lidar, self.inline = lidar, inline
        #: other components' reasons to refuse a goal now (the battery's charge), or None
        self.gates: list[Callable[[], str | None]] = []
        self.points = points or scan_points(config)
        self.area: GridArea = centred_area(settings.resolution, settings.size_m)
        self.costmap = Costmap(self.area, cost_params(config))
        self.costs: np.ndarray | None = None
        #: the planning process (None: plans run in the tick, ``inline``)
        self.worker: PlanningWorker | None = None
        self.navigator = Navigator(navigator_settings(config))
        robot, mapping = config.get(RobotSettings), config.get(MappingSettings)
        self.odom_frame = robot.odom_frame_id
        self.map_frame = mapping.map_frame_id if mapping.enabled else ""
        self.map_to_odom: Pose2 = (0.0, 0.0, 0.0)
        #: the frame of the costmap, the plans and the follower: the map while mapping runs
        #: (the mapper's corrections reach the costmap and the goal), else odometry's
        self.frame = self.map_frame or self.odom_frame
        self.period = 1.0 / settings.control_rate
        self._next_decision = -math.inf
        self._scans: deque[tuple[Pose2, np.ndarray, np.ndarray]] = deque(maxlen=SCAN_QUEUE)
        self._history: deque[tuple[float, Pose2]] = deque()
        self.scan_time: float | None = None
        self._planning = False
        #: how long the robot has been near the goal without the lidar seeing its cell (s)
        self.unseen_near_s = 0.0
        #: the nearest it came to the goal meanwhile (m), and the time since it did (s)
        self.unseen_nearest_m, self.unseen_still_s = math.inf, 0.0
        self._invalidations = control.invalidations - control.stall_invalidations
        self._tasks: set[asyncio.Future[Any]] = set()
        self.plan_ms: float | None = None
        self._published = ""
        if lidar:  # without it no goal starts and no scan needs the pose history
            plugs.add_tick_source(self._tick)
        self.hooks = plugs.while_busy(on_command=self._on_command)
        plugs.subscribe(SCAN, self.on_scan)
        plugs.subscribe(TRANSFORMS, self.on_transforms)
        plugs.add_status("navigation", self.brief)
        self.publisher = StatePublisher(plugs, STATE, self.status)
        self.mission: Mission | None = None  # the last mission (POST /api/mission)
        #: frontier exploration (the autonomy's mode ``explore``): goals chosen by the robot
        self.explorer = Explorer(ExploreSettings())

    # -- inputs --------------------------------------------------------------------------------

    def on_scan(self, scan: LaserScan) -> None:
        now = self.clock()
        self.scan_time = now
        age = min(max(0.0, self.wall_clock() - scan.stamp), HISTORY_S)
        xs, ys = self.points(scan)
        self._scans.append((self._pose_at(now - age), xs, ys))

    def _pose_at(self, t: float) -> Pose2:
        """The robot's pose in :attr:`frame` at control-clock time ``t``."""
        for stamp, pose in reversed(self._history):
            if stamp <= t:
                return self._in_frame(pose)
        return self._here()

    def _in_frame(self, odom_pose: Pose2) -> Pose2:
        """A pose in odometry's frame in :attr:`frame`."""
        return compose(self.map_to_odom, odom_pose) if self.map_frame else odom_pose

    def _here(self) -> Pose2:
        """The robot's pose in :attr:`frame`."""
        return self._in_frame(self._odom())

    def pose(self) -> Pose2:
        """The robot's pose in :attr:`frame` (what goals and the costmap are in)."""
        return self._here()

    def refresh_costs(self) -> np.ndarray | None:
        """Fold the revolutions waiting for the next plan into the costmap now (unless a plan
        is running in the worker: then the last costs) and return the costs."""
        if not self._planning and self._scans:
            self.costs = fold(self.costmap, list(self._scans))
            self._scans.clear()
        return self.costs

    def _odom(self) -> Pose2:
        pose = self.robot.pose()
        return (pose.x, pose.y, pose.theta)

    def on_transforms(self, transforms: tuple[Transform, ...]) -> None:
        for t in transforms:
            if self.map_frame and t.parent == self.map_frame and t.child == self.odom_frame:
                self.map_to_odom = (t.x, t.y, t.theta)

    def _on_command(self, source: str) -> None:
        if self.navigator.active:
            self._end("canceled", f"teleop from {source}")
        elif not self.explorer.running:
            self.hooks.stop()

    # -- goals ---------------------------------------------------------------------------------

    def refusal(self) -> str | None:
        """Why no goal can start now, or None."""
        for gate in self.gates:
            problem = gate()
            if problem:
                return problem
        if not self.lidar:
            return "navigation needs the lidar: enable [lidar]"
        if self.robot.estop_engaged:
            return "e-stop engaged: release it first"
        if self.robot.fault:
            return f"driver fault: {self.robot.fault}"
        return None

    def to_frame(self, frame: str, x: float, y: float, yaw: float) -> Pose2:
        """A pose in ``frame`` (odom, or map while mapping runs) in :attr:`frame`."""
        if frame == self.frame:
            return (x, y, yaw)
        if frame == self.odom_frame:
            return self._in_frame((x, y, yaw))
        frames = " or ".join(repr(f) for f in (self.map_frame, self.odom_frame) if f)
        hint = "" if self.map_frame else " (the map frame needs [mapping] enabled)"
        raise GoalError(f"header.frame_id is {frame!r}: goals are taken in {frames}{hint}")

    def request(self, request: GoalRequest, *, step_of: Mission | None = None,
                explorer: bool = False) -> None:
        """Start ``request``, replacing any goal (and a mission, unless it is ``step_of`` that
        mission, and an exploration, unless the ``explorer`` sends it); a GoalError says why
        it cannot start."""
        refusal = self.refusal()
        if refusal:
            raise GoalError(refusal)
        target = self._target(request)
        if self.explorer.running and not explorer:
            self.stop_exploring("replaced by a goal" if step_of is None
                                else "replaced by a mission")
        if self.mission is not None and self.mission.running and step_of is not self.mission:
            self.mission.finish("canceled", "replaced by a new goal")
        if self.navigator.active:
            log.info("goal %d replaced by a new goal", self.navigator.goals)
            self.navigator.end("canceled", "replaced by a new goal", self.clock())
        self._invalidations = self.robot.invalidations - self.robot.stall_invalidations
        now = self.clock()
        self.navigator.start(target, now)
        self.hooks.start()
        if step_of is not None:
            step_of.step_started(self.navigator.goals, now)
        self._next_decision, self.unseen_near_s = now, 0.0
        self.unseen_nearest_m, self.unseen_still_s = math.inf, 0.0
        if target.path is not None:
            self.bus.publish(PLAN, PlanMessage(self.wall_clock(), self.frame, target.path))
        log.info("goal %d: %s", self.navigator.goals, self._describe(target))
        self.publisher.publish(now)

    def _target(self, request: GoalRequest) -> Target:
        if request.path:
            x, y, theta = self._here()
            points = transform(figure_eight(request.size), (x, y, theta))
            return self._checked(Target(self.frame, x, y, None, points, request.path))
        if request.waypoints:
            points = np.array([(x, y) for x, y, _ in (self.to_frame(request.frame, px, py, 0.0)
                                                      for px, py in request.waypoints)])
            here = np.array([self._here()[:2]])
            last = points[-1]
            return self._checked(Target(self.frame, float(last[0]), float(last[1]), None,
                                        np.vstack((here, points)), "waypoints"))
        yaw = 0.0 if request.yaw is None else request.yaw
        x, y, _ = self.to_frame(request.frame, request.x, request.y, yaw)
        self._check_point(x, y)
        return Target(request.frame, request.x, request.y, request.yaw,
                      xy_tolerance=request.xy_tolerance, yaw_tolerance=request.yaw_tolerance)

    def _checked(self, target: Target) -> Target:
        assert target.path is not None
        for x, y in target.path:
            self._check_point(float(x), float(y))
        return target

    def _check_point(self, x: float, y: float) -> None:
        row, col = self.area.cell(x, y)
        if not self.area.inside(row, col):
            raise GoalError(f"({x:.2f}, {y:.2f}) in {self.frame} is outside the map "
                            f"([navigation] size_m = {self.settings.size_m:g} m around the "
                            f"origin of {self.frame})")
        costs = self.costs
        if costs is not None and self.costmap.seen[row, col] and \
                not math.isfinite(float(costs[row, col])):
            raise GoalError(f"({x:.2f}, {y:.2f}) is inside an obstacle, or too close to one "
                            "for the footprint")

    @staticmethod
    def _describe(target: Target) -> str:
        if target.path is not None:
            return f"follow {target.name} ({len(target.path)} points)"
        yaw = "any heading" if target.yaw is None else f"{math.degrees(target.yaw):.0f} deg"
        return f"({target.x:.2f}, {target.y:.2f}) in {target.frame}, {yaw}"

    def cancel(self, reason: str) -> bool:
        if not self.navigator.active:
            return False
        self._end("canceled", reason)
        return True

    def _end(self, state: str, reason: str) -> None:
        now = self.clock()
        self.navigator.end(state, reason, now)
        self.robot.withdraw(SOURCE)
        log.info("goal %d %s%s", self.navigator.goals, state, f": {reason}" if reason else "")
        self._goal_ended()
        self.publisher.publish(now)

    # -- missions ------------------------------------------------------------------------------

    def start_mission(self, mission: Mission) -> None:
        """Run ``mission`` from its first step, replacing any goal; GoalError: step 1 refused."""
        try:
            self.request(mission.steps[0], step_of=mission)
        except GoalError as exc:
            raise GoalError(f"step 1: {exc}") from None
        self.mission = mission
        log.info("mission %r: %d steps", mission.name, len(mission.steps))

    def _goal_ended(self) -> None:
        """The navigator's goal ended: the explorer or the mission goes on."""
        navigator = self.navigator
        if self.explorer.running and not navigator.active:
            reason = navigator.reason
            problem = self.refusal() or self._failure() or \
                (reason if reason.startswith(ROBOT_PROBLEMS) else None)
            self.explorer.goal_ended(navigator.goals, navigator.state, reason, problem,
                                     self.clock())
        mission = self.mission
        if mission is None or not mission.running or mission.goal_number != navigator.goals \
                or navigator.active:
            return
        now, state, reason = self.clock(), navigator.state, navigator.reason
        while mission.step_ended(state, reason, now):
            try:
                self.request(mission.steps[mission.index], step_of=mission)
                return
            except GoalError as exc:
                state, reason = "failed", f"refused: {exc}"
        log.info("mission %r %s%s", mission.name, mission.state,
                 f": {mission.reason}" if mission.reason else "")

    # -- planning ------------------------------------------------------------------------------

    def _goal_in_frame(self) -> Pose2:
        target = self.navigator.target
        assert target is not None
        return self.to_frame(target.frame, target.x, target.y, target.yaw or 0.0)

    def _request_plan(self, now: float) -> None:
        self.navigator.planning(now)
        target = self.navigator.target
        assert target is not None
        scans = list(self._scans)
        self._scans.clear()
        start, goal = self._here(), self._goal_in_frame()
        yaw = None if target.yaw is None else goal[2]
        block = self.settings.plan_block
        if self.inline:
            self._take_plan(fold_and_plan(self.costmap, scans, start, goal, block),
                            target.number, yaw)
            return
        self._planning = True
        future = asyncio.ensure_future(self._worker().plan(scans, start, goal, block))
        self._tasks.add(future)
        future.add_done_callback(lambda f: self._planned(f, target.number, yaw))

    def _planned(self, future: asyncio.Future[Planned], number: int,
                 yaw: float | None) -> None:
        self._tasks.discard(future)
        self._planning = False
        if future.cancelled():
            return
        exc = future.exception()
        if isinstance(exc, WorkerDown):
            log.warning("planning failed: %s", exc)
            self._end("failed", f"the planner failed: {exc}")
            return
        if exc is not None:
            log.error("planning failed: %r", exc)
            self._end("failed", f"the planner failed: {exc!r}")
            return
        self._take_plan(future.result(), number, yaw)

    def _take_plan(self, planned: Planned, number: int, yaw: float | None) -> None:
        self.costs, self.plan_ms, result = planned.costs, planned.ms, planned.plan
        navigator = self.navigator
        state = navigator.state
        if navigator.planned(result, self.clock(), number, yaw):
            self.bus.publish(PLAN, PlanMessage(self.wall_clock(), self.frame, result.points))
        if navigator.state != state:
            self._state_changed(state)

    # -- the tick ------------------------------------------------------------------------------

    def _tick(self, now: float) -> None:
        history, odom = self._history, self.robot.pose_xyt()
        if not history or history[-1][1] != odom:  # a pose held since is the same pose
            history.append((now, odom))
        while len(history) > 1 and history[1][0] <= now - HISTORY_S:
            history.popleft()  # the newest pose as old as the horizon stays: it still holds
        if self.explorer.wants_look(now) and not self._planning:
            self._look(now)
        navigator = self.navigator
        if not navigator.active or now < self._next_decision:
            return
        self._next_decision = now + self.period - 1e-9
        failure = self._failure() or self._never_seen()
        if failure is not None:
            self._end("failed", failure)
            return
        state = navigator.state
        if navigator.wants_plan(now) and not self._planning:
            self._request_plan(now)
        stale = self.scan_time is None or now - self.scan_time > SCAN_TIMEOUT_S
        v, w = navigator.decide(now, self._here(), self.robot.odometry_speed(),
                                "no fresh lidar scan" if stale else None, self._held())
        if navigator.active:
            self.robot.propose(SOURCE, Twist(v, w), now, PRIORITY)
        if navigator.state != state:
            self._state_changed(state)

    def _state_changed(self, previous: str) -> None:
        navigator = self.navigator
        log.info("goal %d: %s -> %s%s", navigator.goals, previous, navigator.state,
                 f" ({navigator.reason})" if navigator.reason else "")
        if not navigator.active:
            self.robot.withdraw(SOURCE)
            self._goal_ended()
        self.publisher.publish(self.clock())

    def _failure(self) -> str | None:
        robot = self.robot
        if robot.estop_engaged:
            return "e-stop engaged"
        if robot.fault:
            return f"driver fault: {robot.fault}"
        if robot.invalidations - robot.stall_invalidations != self._invalidations:
            return "e-stop or driver fault in between: send the goal again"
        return None

    def _never_seen(self) -> str | None:
        """Why the goal is taken for unreachable: its cell stays unseen though the robot has
        been near it long enough (a lidar never sees inside an obstacle or a closed room)."""
        target = self.navigator.target
        if target is None or target.path is not None:
            return None
        x, y, _ = self._goal_in_frame()
        here = self._here()
        row, col = self.area.cell(x, y)
        distance = math.hypot(x - here[0], y - here[1])
        if not self.area.inside(row, col) or self.costmap.seen[row, col] \
                or distance > UNSEEN_NEAR_M:
            return None
        self.unseen_near_s += self.period
        if distance < self.unseen_nearest_m - UNSEEN_GAIN_M:
            self.unseen_nearest_m, self.unseen_still_s = distance, 0.0
        else:
            self.unseen_still_s += self.period
        if self.unseen_near_s < UNSEEN_FAIL_S or self.unseen_still_s < UNSEEN_STILL_S:
            return None
        return (f"the lidar never saw the goal though the robot was within "
                f"{UNSEEN_NEAR_M:g} m of it for {UNSEEN_FAIL_S:g} s and came no nearer: it "
                "lies inside an obstacle or a closed room")

    def _held(self) -> bool:
        return self.robot.safety_action() == "stop"

    # -- exploration ---------------------------------------------------------------------------

    @property
    def exploring(self) -> bool:
        return self.explorer.running

    def start_exploring(self, reason: str) -> str | None:
        """Start exploring from here (replacing any goal); why it cannot, or None."""
        refusal = self.refusal()
        if refusal:
            return refusal
        if self.explorer.running:
            return None
        self.cancel("replaced by exploration")
        if self.mission is not None and self.mission.running:
            self.mission.finish("canceled", "replaced by exploration")
        now = self.clock()
        self.explorer.start(now, self._here())
        log.info("exploring (%s)", reason)
        self.publisher.publish(now)
        return None

    def stop_exploring(self, reason: str) -> None:
        """End the exploration ``canceled`` and stop its goal."""
        explorer = self.explorer
        if not explorer.running:
            return
        explorer.end("canceled", reason, self.clock())
        log.info("exploration canceled: %s", reason)
        if self.navigator.active and self.navigator.goals == explorer.goal_number:
            self._end("canceled", reason)
        else:
            self.publisher.publish(self.clock())

    def exploration(self) -> dict[str, Any]:
        return self.explorer.status(self.clock())

    def _look(self, now: float) -> None:
        """Fold the revolutions in and find the frontiers (in the worker, as a plan)."""
        scans = list(self._scans)
        self._scans.clear()
        start = self._here()
        job = (scans, start, self.explorer.settings.min_frontier_cells, self.settings.plan_block)
        if self.inline:
            self._looked(fold_and_look(self.costmap, *job))
            return
        self._planning = True
        future = asyncio.ensure_future(self._worker().look(*job))
        self._tasks.add(future)
        future.add_done_callback(self._look_done)

    def _look_done(self, future: asyncio.Future[Looked]) -> None:
        self._tasks.discard(future)
        self._planning = False
        if future.cancelled():
            return
        if future.exception() is not None:
            log.error("looking for frontiers failed: %r", future.exception())
            self.explorer.end("failed", f"looking for frontiers failed: {future.exception()!r}",
                              self.clock())
            return
        self._looked(future.result())

    def _looked(self, looked: Looked) -> None:
        self.costs = looked.costs
        frontiers, explored_m2 = looked.frontiers, looked.explored_m2
        explorer, navigator = self.explorer, self.navigator
        now = self.clock()
        state = explorer.state
        following = navigator.active and navigator.goals == explorer.goal_number
        go = explorer.looked(now, frontiers, explored_m2, following)
        if go is not None:
            self._go(go, now)
        if explorer.state != state:
            log.info("exploration %s -> %s%s", state, explorer.state,
                     f" ({explorer.reason})" if explorer.reason else "")
            self.publisher.publish(now)

    def _go(self, go: Go, now: float) -> None:
        try:
            self.request(GoalRequest(self.frame, go.x, go.y, go.yaw), explorer=True)
        except GoalError as exc:
            self.explorer.refused(go, str(exc), now)
            return
        self.explorer.sent(self.navigator.goals)

    # -- reports -------------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        nav = self.navigator
        out: dict[str, Any] = {"state": nav.state, "reason": nav.reason, "goals": nav.goals}
        target = nav.target
        if target is not None:
            out["goal"] = ({"path": target.name, "points": len(target.path)}
                           if target.path is not None else
                           {"frame": target.frame, "x": target.x, "y": target.y,
                            "theta": target.yaw})
            progress = nav.progress
            out.update(
                distance_remaining_m=round(nav.last.remaining_m, 3), eta_s=nav.eta_s(),
                elapsed_s=round(max(0.0, self.clock() - progress.started), 2),
                recoveries=progress.recoveries, replans=progress.replans,
                plan_length_m=round(nav.pursuit.length, 3) if nav.pursuit else None,
                plan_ms=self.plan_ms,
                tracking={"rms_m": round(progress.tracking.rms, 4),
                          "max_m": round(progress.tracking.worst, 4)})
        if self.mission is not None:
            out["mission"] = self.mission.report()
        if self.explorer.state != "idle":
            out["exploration"] = self.exploration()
        return out

    def brief(self) -> dict[str, Any]:
        status = self.status()
        keys = ("state", "reason", "distance_remaining_m", "eta_s")
        out = {k: status[k] for k in keys if k in status}
        if "exploration" in status:
            explored = status["exploration"]
            out["exploration"] = {k: explored[k] for k in ("state", "reason", "explored_m2")}
        return out

    def health(self) -> Health:
        # without a lidar nothing is wrong with the robot: goals are refused, saying why
        if not self.lidar:
            return Health("ok", "no lidar: goals are refused; enable [lidar]", self.status())
        status = self.status()
        down = self.worker.worker.problem() if self.worker is not None else None
        if self.worker is not None:
            status["worker"] = self.worker.worker.values()
        if down is not None:
            return Health(down[0], f"{down[1]}; goals fail until it is back", status)
        return Health("ok", values=status)

    # -- HTTP and topics -----------------------------------------------------------------------

    async def get_goal(self, request: web.Request) -> web.Response:
        return json_response(self.status())

    async def post_goal(self, request: web.Request) -> web.Response:
        return await self._start_posted(request, 65536, goal_of_json, self.request, "goal")

    async def post_mission(self, request: web.Request) -> web.Response:
        return await self._start_posted(request, 262144, mission_of_json, self.start_mission,
                                        "mission")

    async def _start_posted(self, request: web.Request, limit: int,
                            parse: Callable[[dict[str, Any], str], T],
                            start: Callable[[T], None], what: str) -> web.Response:
        """A goal or mission from a JSON body: 422 when malformed, 409 when it cannot start."""
        body = await read_json_object(request, limit)
        try:
            item = parse(body, self.map_frame or self.odom_frame)
        except GoalError as exc:
            raise ApiError(422, f"invalid {what}: {exc}") from None
        try:
            start(item)
        except GoalError as exc:
            raise ApiError(409, f"{what} refused: {exc}") from None
        return json_response(self.status())

    async def delete_goal(self, request: web.Request) -> web.Response:
        self.cancel("canceled over HTTP")
        return json_response(self.status())

    async def on_goal_pose(self, message: Inbound) -> Refusal | None:
        """``/goal_pose`` (geometry_msgs/PoseStamped): go there."""
        try:
            self.request(goal_of_pose_stamped(message.msg))
        except GoalError as exc:
            return Refusal(f"goal refused: {exc}")
        return None

    async def on_clicked_point(self, message: Inbound) -> Refusal | None:
        """``/clicked_point``: Foxglove advertises it on every connection; not used."""
        return None

    def routes(self) -> Sequence[Route]:
        return (Route("GET", "/api/goal", self.get_goal, "read"),
                Route("POST", "/api/goal", self.post_goal, "drive"),
                Route("DELETE", "/api/goal", self.delete_goal, "drive"),
                Route("POST", "/api/mission", self.post_mission, "drive"))

    def topics(self) -> Sequence[Topic]:
        return (TopicIn("/goal_pose", POSE_STAMPED, self.on_goal_pose, "drive",
                        required=("pose.position.x", "pose.position.y")),
                TopicIn("/clicked_point", POINT_STAMPED, self.on_clicked_point, "drive"),  # unused
                TopicOut("/plan", PATH, PLAN, path_msg, "on every new plan", latched=True),
                TopicOut("/navigation/state", STRING, STATE, json_string_msg,
                         "on change + 1 Hz"))

    def _worker(self) -> PlanningWorker:
        """The planning process, started with the first job (a daemon nobody sends a goal
        spawns none); the cells folded so far go with it."""
        if self.worker is None:
            self.worker = worker = PlanningWorker(self.area, self.costmap.params)
            worker.costmap.evidence[...] = self.costmap.evidence
            worker.costmap.seen[...] = self.costmap.seen
            self.costmap = worker.costmap
        return self.worker

    async def stop(self) -> None:
        if self.navigator.active:
            self._end("canceled", "daemon stopping")
        for task in list(self._tasks):
            task.cancel()
        if self.worker is not None:
            worker, self.worker = self.worker, None
            await asyncio.to_thread(worker.close)


def create(ctx: DaemonContext) -> NavigationComponent | None:
    """The navigation component when ``[navigation] enabled``."""
    if not ctx.settings(NavigationSettings).enabled:
        return None
    return NavigationComponent(ctx.config, ctx.plugs, lidar=ctx.settings(LidarSettings).enabled,
                               points=ctx.scan_points)


COMPONENT = ComponentSpec("navigation", create, NavigationSettings)
