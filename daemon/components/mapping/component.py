# The "mapping" component: each lidar revolution corrects the odometry pose and grows the map.
from __future__ import annotations

import asyncio
import base64
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from aiohttp import web

from daemon.bus import BusKey
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Plugs, Route
from daemon.components.mapping import messages
from daemon.components.mapping.mapfile import (
    MapData,
    MapFileError,
    load_map,
    pgm_bytes,
    save_map,
    saved_maps,
)
from daemon.components.mapping.runner import (
    InlineRunner,
    MapperRunner,
    MapSnapshot,
    ProcessRunner,
    snapshot_of,
)
from daemon.components.mapping.settings import MappingSettings, map_name_error
from daemon.coords import CoordinateError, Extent
from daemon.files import FileRefused, sees_paths, serve_file, shown
from daemon.health import Health
from daemon.messages.definitions import OCCUPANCY_GRID, POSE_WITH_COVARIANCE_STAMPED
from daemon.paths import state_directory
from daemon.security import Security
from daemon.settings import RobotSettings
from daemon.telemetry import POWER, SCAN, TRANSFORMS, PowerEvent, Transform
from daemon.topics import Inbound, Refusal, Topic, TopicIn, TopicOut
from daemon.web import ApiError, HttpPort, json_response, read_json_object
from daemon.workers import WorkerDown
from sensors.rplidar.settings import LidarSettings
from sensors.scan import LaserScan, ScanPoints
from slam.mapper import MapperConfig, ScanResult
from slam.pose import Pose2, compose, inverse

log = logging.getLogger("arbiterd.mapping")

#: the map as nav_msgs/OccupancyGrid wants it, on change and at most every publish_period_s
MAP: BusKey[messages.MapMessage] = BusKey("map")
#: the robot's pose in the map after each matched revolution
MAP_POSE: BusKey[messages.MapPose] = BusKey("map_pose")
#: odometry poses kept to place a revolution at its own time (s)
HISTORY_S = 2.0
#: revolutions that may wait behind a busy mapper (a key scan or a loop closure takes a few
#: revolutions' time now and then); beyond this the oldest is dropped
QUEUE_LENGTH = 20
#: a revolution that waited longer than this is dropped (s)
MAX_QUEUE_AGE_S = 2.0


#: one revolution for the mapper: odometry pose, points (robot frame), stamp, control time
Job = tuple[Pose2, np.ndarray, float, float]


@dataclass
class Counters:
    scans: int = 0
    skipped_busy: int = 0
    skipped_no_odometry: int = 0
    failed: int = 0
    maps_published: int = 0


class MappingComponent(BaseComponent):
    """Feeds every revolution, placed at the odometry pose of its time, to the mapper
    (:mod:`slam`), then publishes what it says: the pose in the map, ``map -> odom`` on
    /tf, and the map (throttled, only when it changed). The mapper runs in a worker process
    (``inline=False``) or in the caller's thread (the lockstep simulator: repeatable)."""

    name = "mapping"
    core = False

    def __init__(self, settings: MappingSettings, plugs: Plugs, points: ScanPoints, *,
                 maps_dir: Path, base_frame_id: str = "base_link",
                 odom_frame_id: str = "odom", inline: bool = False,
                 wall_clock: Callable[[], float] = time.time,
                 http: HttpPort | None = None, security: Security | None = None) -> None:
        self.settings = settings
        self.http, self.security = http, security or Security("")
        self.bus = plugs.bus
        self.robot = plugs.robot
        self.clock = self.robot.clock
        self.wall_clock = wall_clock
        self.points = points
        self.maps_dir = maps_dir
        self.frames = (settings.map_frame_id, odom_frame_id, base_frame_id)
        self.inline = inline
        self.counters = Counters()
        self.history: deque[tuple[float, float, float, float]] = deque()
        self.runner: MapperRunner | None = None
        self.last: ScanResult | None = None
        #: the odometry pose the last revolution was placed at
        self.last_odom: Pose2 | None = None
        self.map_version = 0
        self.map_name = settings.map if settings.mode == "localize" else ""
        self.problem = ""
        self._busy = False
        self._pending: deque[Job] = deque()
        self._next_map_at = -math.inf
        self._tasks: set[asyncio.Task[Any]] = set()
        plugs.on_tick(self._on_tick)
        plugs.subscribe(SCAN, self.on_scan)
        plugs.subscribe(POWER, self._on_power)

    # -- lifecycle ------------------------------------------------------------------------------

    def mapper_config(self) -> MapperConfig:
        s = self.settings
        return MapperConfig(resolution=s.resolution, max_range=s.max_range_m, mode=s.mode,
                            loop_closure=s.loop_closure, max_cells=s.max_cells)

    async def start(self) -> None:
        grid = None
        if self.settings.mode == "localize":
            grid = self._load_for_localize(self.settings.map)
            if grid is None:
                return
        self.runner = self._runner(grid, self._initial_pose())
        if grid is not None and self.settings.find_pose:
            await self.runner.find_pose()
        if not self.inline:  # the worker's start-up (its imports) before the first revolution
            self._spawn(self._warm_up(self.runner))

    async def _warm_up(self, runner: MapperRunner) -> None:
        try:
            await runner.health()
        except WorkerDown as exc:
            self._lost(exc)
        except Exception as exc:
            self._fail(exc)

    def _runner(self, grid: MapData | None, pose: Pose2) -> MapperRunner:
        config = self.mapper_config()
        if self.inline:
            return InlineRunner(config, grid, pose)
        return ProcessRunner(config, grid, pose)

    def _initial_pose(self) -> Pose2:
        x, y, heading = self.settings.initial_pose
        return (x, y, math.radians(heading))

    def _load_for_localize(self, name: str) -> MapData | None:
        if not name:
            self.problem = "[mapping] mode = \"localize\" needs map = NAME (arbiterd map list)"
            log.error("%s", self.problem)
            return None
        try:
            grid = self.load(name)
        except MapFileError as exc:
            self.problem = f"cannot localise: {exc}"
            log.error("%s", self.problem)
            return None
        return grid

    def load(self, name: str) -> MapData:
        """A saved map, checked against [mapping] resolution."""
        grid = load_map(self.maps_dir / f"{name}.yaml", self.settings.max_cells)
        if not math.isclose(grid.resolution, self.settings.resolution, rel_tol=1e-6):
            raise MapFileError(f"map {name!r} has {grid.resolution:g} m cells, [mapping] "
                               f"resolution is {self.settings.resolution:g}: set it to "
                               f"{grid.resolution:g} or save the map again")
        return grid

    async def stop(self) -> None:
        for task in list(self._tasks):
            task.cancel()
        if self.runner is not None:
            runner, self.runner = self.runner, None
            await asyncio.to_thread(runner.close)

    # -- the robot's pose at a revolution -------------------------------------------------------

    def odom_at(self, t: float) -> Pose2 | None:
        """The odometry pose at control-clock time ``t``, interpolated between ticks."""
        history = self.history
        if not history or t < history[0][0] - 0.05:
            return None
        later = history[-1]
        if t >= later[0]:
            return later[1:]
        for earlier in reversed(history):
            if earlier[0] <= t:
                span = later[0] - earlier[0]
                f = (t - earlier[0]) / span if span > 0 else 1.0
                turn = math.remainder(later[3] - earlier[3], math.tau)
                return (earlier[1] + f * (later[1] - earlier[1]),
                        earlier[2] + f * (later[2] - earlier[2]), earlier[3] + f * turn)
            later = earlier
        return history[0][1:]

    # -- revolutions ----------------------------------------------------------------------------

    def on_scan(self, scan: LaserScan) -> None:
        if self.runner is None:
            return
        now = self.clock()
        age = min(max(0.0, self.wall_clock() - scan.stamp), 60.0)
        odom = self.odom_at(now - age)
        if odom is None:
            self.counters.skipped_no_odometry += 1
            return
        xs, ys = self.points(scan)
        job = (odom, np.column_stack((xs, ys)), scan.stamp, now)
        self.last_odom = odom
        if self.inline:
            assert isinstance(self.runner, InlineRunner)
            self._apply(self.runner.mapper.add_scan(*job[:3]), job[2])
            return
        if self._busy:
            if len(self._pending) >= QUEUE_LENGTH:
                self._pending.popleft()
                self.counters.skipped_busy += 1
            self._pending.append(job)
            return
        self._spawn(self._match(job))

    def _spawn(self, coroutine: Any) -> None:
        task = asyncio.get_running_loop().create_task(coroutine)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _match(self, first: Job) -> None:
        self._busy = True
        job: Job | None = first
        try:
            while job is not None and self.runner is not None:
                odom, points, stamp, _ = job
                try:
                    result = await self.runner.add_scan(odom, points, stamp)
                except WorkerDown as exc:  # restarted by its supervisor: skip, go on
                    self._lost(exc)
                    return
                except Exception as exc:  # the mapper failed
                    self._fail(exc)
                    return
                self._apply(result, stamp)
                job = self._take_pending()
        finally:
            self._busy = False

    def _take_pending(self) -> Job | None:
        while self._pending:
            job = self._pending.popleft()
            if self.clock() - job[3] <= MAX_QUEUE_AGE_S:
                return job
            self.counters.skipped_busy += 1
        return None

    def _lost(self, exc: WorkerDown) -> None:
        """A revolution or a map lost because the worker is down: counted, not fatal."""
        self.counters.failed += 1
        self._pending.clear()
        log.debug("mapping: %s", exc)

    def _fail(self, exc: BaseException) -> None:
        self.counters.failed += 1
        self.problem = f"the mapper failed: {type(exc).__name__}: {exc}"
        log.error("%s; mapping stopped (restart the daemon to map again)", self.problem)
        self.runner = None

    def _apply(self, result: ScanResult, stamp: float) -> None:
        self.counters.scans += 1
        self.last = result
        if isinstance(self.runner, ProcessRunner):
            self.runner.moved_to(result.pose)
        map_frame, odom_frame, _base_frame = self.frames
        self.bus.publish(TRANSFORMS, (Transform(stamp, map_frame, odom_frame,
                                                *result.map_to_odom),))
        self.bus.publish(MAP_POSE, messages.MapPose(stamp, map_frame, result))

    # -- the map --------------------------------------------------------------------------------

    def _on_tick_map(self, now: float) -> None:
        if now < self._next_map_at or self.runner is None:
            return
        self._next_map_at = now + self.settings.publish_period_s
        if self.inline:
            assert isinstance(self.runner, InlineRunner)
            self._publish_map(snapshot_of(self.runner.mapper, self.map_version))
        elif not any(t.get_name() == "map" for t in self._tasks):
            self._spawn_named(self._fetch_map(), "map")

    def _spawn_named(self, coroutine: Any, name: str) -> None:
        task = asyncio.get_running_loop().create_task(coroutine, name=name)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _fetch_map(self) -> None:
        if self.runner is None:
            return
        try:
            snapshot = await self.runner.snapshot(self.map_version)
        except WorkerDown as exc:
            self._lost(exc)
            return
        except Exception as exc:
            self._fail(exc)
            return
        self._publish_map(snapshot)

    def _publish_map(self, snapshot: MapSnapshot | None) -> None:
        if snapshot is None:
            return
        self.map_version = snapshot.version
        self.latest_map = snapshot.grid
        self.counters.maps_published += 1
        self.bus.publish(MAP, messages.MapMessage(self.wall_clock(), self.frames[0],
                                                  snapshot.grid))

    latest_map: MapData | None = None

    # -- poses from outside ---------------------------------------------------------------------

    async def set_pose(self, pose: Pose2) -> None:
        """Localise from ``pose`` (map frame) at the current odometry."""
        grid = self.latest_map
        if grid is not None:
            extent = Extent(grid.origin_x, grid.origin_y,
                            grid.origin_x + grid.width * grid.resolution,
                            grid.origin_y + grid.height * grid.resolution)
            try:
                extent.check(pose[0], pose[1], "x, y")
            except CoordinateError as exc:
                raise ApiError(422, f"invalid pose: {exc}") from None
        if self.runner is None:
            raise ApiError(409, f"mapping is not running: {self.problem or 'no mapper'}")
        odom = self.robot.pose()
        await self.runner.set_pose(pose, (odom.x, odom.y, odom.theta))
        log.info("pose in the map set to (%.2f m, %.2f m, %.0f deg)", pose[0], pose[1],
                 math.degrees(pose[2]))

    async def on_initial_pose(self, message: Inbound) -> Refusal | None:
        """``/initialpose`` (what RViz and Foxglove publish): a pose in the map frame."""
        try:
            pose = messages.pose_of(message.msg, self.frames[0])
        except ValueError as exc:
            return Refusal(str(exc))
        try:
            await self.set_pose(pose)
        except ApiError as exc:
            return Refusal(str(exc))
        return None

    # -- HTTP -----------------------------------------------------------------------------------

    async def get_map(self, request: web.Request) -> web.Response:
        grid = self.latest_map
        if grid is None:
            raise ApiError(404, "no map yet", {"mapping": self.status()})
        if request.query.get("format") == "pgm":
            return web.Response(body=pgm_bytes(grid.occupancy),
                                content_type="image/x-portable-graymap")
        return json_response({
            "resolution": grid.resolution, "width": grid.width, "height": grid.height,
            "origin": [grid.origin_x, grid.origin_y], "frame_id": self.frames[0],
            "version": self.map_version,
            "data": base64.b64encode(grid.occupancy.tobytes()).decode(),
            "encoding": "int8 row-major from the origin, base64; -1 unknown, 0-100 occupied"})

    async def post_save(self, request: web.Request) -> web.Response:
        body = await read_json_object(request, 4096)
        name = body.get("name")
        if not isinstance(name, str) or map_name_error(name):
            raise ApiError(422, f"invalid map name: {map_name_error(str(name))}")
        return json_response(await self.save(name))

    def _on_power(self, event: PowerEvent) -> None:
        """Critical charge: save the map being built (the write is atomic) while there is
        power to do it."""
        if event.level == "critical" and self.settings.mode != "localize":
            self._spawn(self._save_before_power_off(event))

    async def _save_before_power_off(self, event: PowerEvent) -> None:
        name = time.strftime("power-off-%Y%m%d-%H%M%S", time.localtime(event.stamp))
        try:
            saved = await self.save(name)
            log.warning("mapping: %s: map saved as %s", event.reason, saved["yaml"])
        except ApiError as exc:
            log.warning("mapping: %s: map not saved: %s", event.reason, exc.message)

    async def save(self, name: str) -> dict[str, Any]:
        """Write the current map as NAME.yaml + NAME.pgm in the maps directory."""
        await self._fetch_map()
        grid = self.latest_map
        if grid is None:
            raise ApiError(409, "no map to save yet: drive until the lidar has seen some walls")
        try:
            pgm, yml = await asyncio.to_thread(save_map, self.maps_dir, name, grid,
                                               int(self.settings.max_saved_mb * 1e6))
        except FileRefused as exc:
            raise ApiError(507, f"map not saved: {exc.strerror}", "delete saved maps or raise "
                           "[mapping] max_saved_mb") from None
        except OSError as exc:
            raise ApiError(500, f"cannot save the map in {self.maps_dir}: {exc.strerror}; "
                           "set [mapping] directory to a writable folder") from None
        log.info("map saved: %s (%d x %d cells)", yml, grid.width, grid.height)
        return {"name": name, "yaml": yml.name, "image": pgm.name, "width": grid.width,
                "height": grid.height, "resolution": grid.resolution}

    async def get_maps(self, request: web.Request) -> web.Response:
        maps = await asyncio.to_thread(saved_maps, self.maps_dir)
        return json_response({"maps": shown(sees_paths(self.security, request), maps)})

    async def get_map_file(self, request: web.Request) -> web.StreamResponse:
        filename = request.match_info["file"]
        stem, _, extension = filename.rpartition(".")
        missing = f"no map file {filename[:80]!r} (GET /api/maps lists them)"
        if extension not in ("yaml", "pgm") or map_name_error(stem):
            raise ApiError(404, f"{missing}: ask for NAME.yaml or NAME.pgm")
        content_type = "application/x-yaml" if extension == "yaml" else \
            "image/x-portable-graymap"
        assert self.http is not None, "routes are served only with ctx.http"
        return await serve_file(self.http, request, self.maps_dir, filename, content_type,
                                missing)

    async def post_pose(self, request: web.Request) -> web.Response:
        body = await read_json_object(request, 4096)
        try:
            pose = messages.pose_of_json(body)
        except ValueError as exc:
            raise ApiError(422, f"invalid pose: {exc}") from None
        await self.set_pose(pose)
        return json_response(self.status())

    async def post_load(self, request: web.Request) -> web.Response:
        """Localise in a saved map from now on; a map that cannot be used changes nothing."""
        body = await read_json_object(request, 4096)
        name = body.get("name")
        if not isinstance(name, str) or map_name_error(name):
            raise ApiError(422, f"invalid map name: {map_name_error(str(name))}")
        find = "pose" not in body and self.settings.find_pose
        try:
            grid = await asyncio.to_thread(self.load, name)
            pose = messages.pose_of_json(body.get("pose", {"x": 0, "y": 0, "theta": 0}))
        except (MapFileError, ValueError) as exc:
            raise ApiError(422, f"map not loaded, the old one stays: {exc}") from None
        old = self.runner
        self.settings = self.settings.__class__.from_values(
            {**self.settings.__dict__, "mode": "localize", "map": name})
        self.runner, self.map_name, self.problem = self._runner(grid, pose), name, ""
        self.map_version, self.last = 0, None
        if find:
            await self.runner.find_pose()
        if old is not None:
            await asyncio.to_thread(old.close)
        await self._fetch_map()
        return json_response(self.status())

    # -- component ------------------------------------------------------------------------------

    def routes(self) -> Sequence[Route]:
        return (Route("GET", "/api/map", self.get_map, "read"),
                Route("POST", "/api/map/save", self.post_save, "drive"),
                Route("POST", "/api/map/load", self.post_load, "drive"),
                Route("GET", "/api/maps", self.get_maps, "read"),
                Route("GET", "/api/maps/{file}", self.get_map_file, "read"),
                Route("POST", "/api/pose", self.post_pose, "drive"))

    def topics(self) -> Sequence[Topic]:
        return (TopicOut("/map", OCCUPANCY_GRID, MAP, messages.map_msg,
                         f"on change, at most every {self.settings.publish_period_s:g} s",
                         latched=True, bulk=True),
                TopicOut("/pose", POSE_WITH_COVARIANCE_STAMPED, MAP_POSE, messages.pose_msg,
                         "per revolution"),
                TopicIn("/initialpose", POSE_WITH_COVARIANCE_STAMPED, self.on_initial_pose,
                        "drive", required=("pose.pose.position.x", "pose.pose.position.y")))

    def status(self) -> dict[str, Any]:
        last, c = self.last, self.counters
        out: dict[str, Any] = {
            "mode": self.settings.mode, "map": self.map_name, "running": self.runner is not None,
            "revolutions": c.scans, "skipped_busy": c.skipped_busy,
            "skipped_no_odometry": c.skipped_no_odometry, "maps_published": c.maps_published,
            "map_version": self.map_version}
        if last is not None:
            out.update(pose=[round(last.pose[0], 3), round(last.pose[1], 3),
                             round(math.degrees(last.pose[2]), 1)],
                       matched=last.matched, score=round(last.score, 3), lost=last.lost,
                       localisation=last.status,
                       candidates=[[round(p[0], 3), round(p[1], 3), round(math.degrees(p[2]), 1),
                                    round(score, 3)] for p, score in last.candidates])
        if self.latest_map is not None:
            m = self.latest_map
            out["map_size"] = {"width": m.width, "height": m.height,
                               "resolution": m.resolution}
        if self.problem:
            out["problem"] = self.problem
        return out

    def health(self) -> Health:
        status = self.status()
        problem = status.pop("problem", None)
        if self.problem:
            return Health("error", str(problem or self.problem), status)
        worker = self.runner.worker if isinstance(self.runner, ProcessRunner) else None
        down = worker.problem() if worker is not None else None
        if worker is not None:
            status["worker"] = worker.values()
        if down is not None:
            return Health(down[0], f"{down[1]} (the map since the last save starts anew)"
                          if self.settings.mode == "map" else down[1], status)
        if status.get("localisation") == "ambiguous":
            return Health("degraded", "the robot's view fits several places of the map alike "
                          "(candidates): drive on, or set the pose", status)
        if status.get("localisation") == "searching":
            return Health("degraded", "searching the whole map for the robot's pose", status)
        if status.get("lost"):
            return Health("degraded", "localisation lost: set the pose (/initialpose, "
                          "POST /api/pose) or drive where the map is known", status)
        return Health("ok", values=status)

    def _on_tick(self, now: float, on_time: bool) -> None:
        self._record_odometry(now)
        self._on_tick_map(now)

    def _record_odometry(self, now: float) -> None:
        pose = self.robot.pose()
        history = self.history
        history.append((now, pose.x, pose.y, pose.theta))
        while history and history[0][0] < now - HISTORY_S:
            history.popleft()


def map_to_odom(map_pose: Pose2, odom_pose: Pose2) -> Pose2:
    """The transform that puts the odometry frame where the map says the robot is."""
    return compose(map_pose, inverse(odom_pose))


def maps_directory(settings: MappingSettings) -> Path:
    """[mapping] directory, else maps/ in the state directory."""
    return Path(settings.directory).expanduser() if settings.directory else \
        state_directory("maps")


def create(ctx: DaemonContext) -> MappingComponent | None:
    """The mapping component when ``[mapping] enabled``; it needs the lidar."""
    settings = ctx.settings(MappingSettings)
    if not settings.enabled:
        return None
    if not ctx.settings(LidarSettings).enabled:
        raise ValueError("enabled = true needs the lidar: set [lidar] enabled = true")
    robot = ctx.settings(RobotSettings)
    return MappingComponent(settings, ctx.plugs, ctx.scan_points,
                            maps_dir=maps_directory(settings),
                            base_frame_id=robot.base_frame_id,
                            odom_frame_id=robot.odom_frame_id, http=ctx.http,
                            security=ctx.security)


COMPONENT = ComponentSpec("mapping", create, MappingSettings)
