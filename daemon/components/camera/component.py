# The "camera" component: frames on demand, /api/camera/snapshot and /stream, camera topics.
from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import socket
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from aiohttp import web

from daemon.bus import Bus, BusKey
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Route
from daemon.components.camera.frames import LatestFrame, mjpeg_part
from daemon.components.camera.settings import DRIVERS, CameraSectionSettings
from daemon.health import Health
from daemon.messages.convert import Blob, header
from daemon.messages.definitions import CAMERA_INFO, COMPRESSED_IMAGE
from daemon.topics import Topic, TopicOut
from daemon.web import ApiError, json_response, read_json_object
from drivers.camera import Camera, Frame
from drivers.devices import DeviceError, create_device
from sim.camera import CameraModel

log = logging.getLogger("arbiterd.camera")

@dataclass(frozen=True, slots=True)
class CameraInfo:
    """What sensor_msgs/CameraInfo says of the images: size and the pinhole model."""

    stamp: float
    frame_id: str
    width: int
    height: int
    k: tuple[float, ...]


#: every frame the camera makes (JPEG), while someone watches
CAMERA_IMAGE: BusKey[Frame] = BusKey("camera_image")
#: the camera's intrinsics with each frame (and once a second for a subscriber of it alone)
CAMERA_INFO_KEY: BusKey[CameraInfo] = BusKey("camera_info")
BOUNDARY = "arbiterdframe"
#: how often an idle camera looks whether someone started watching through the bus, s
DEMAND_POLL_S = 0.5
#: reopening a camera that failed: first and longest wait, s
RETRY_MIN_S, RETRY_MAX_S = 1.0, 10.0


def compressed_msg(frame: Frame, frame_id: str = "camera") -> dict[str, Any]:
    return {"header": header(frame.stamp, frame_id), "format": "jpeg", "data": Blob(frame.jpeg)}


def camera_info_msg(info: CameraInfo) -> dict[str, Any]:
    f, cx, cy = info.k[0], info.k[2], info.k[5]
    return {"header": header(info.stamp, info.frame_id), "height": info.height,
            "width": info.width, "distortion_model": "plumb_bob", "d": [0.0] * 5,
            "k": list(info.k), "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            "p": [f, 0.0, cx, 0.0, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
            "binning_x": 0, "binning_y": 0,
            "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0,
                    "do_rectify": False}}


def camera_model(settings: CameraSectionSettings) -> CameraModel:
    return CameraModel(settings.width, settings.height, math.radians(settings.hfov_deg),
                       settings.mount_x, settings.mount_y, settings.mount_z,
                       math.radians(settings.mount_yaw_deg))


class CameraComponent(BaseComponent):
    """Makes frames only while someone wants them — an MJPEG viewer, a snapshot, a bus
    subscriber of the camera topics (rosbridge, the DDS face, the recorder) — on a thread
    of its own (grab and encode never run on the event loop), at ``fps``. Each frame goes
    on the bus (``CAMERA_IMAGE``) and into :class:`LatestFrame` for the HTTP viewers. With
    nobody watching for ``idle_close_s`` the camera is closed."""

    name = "camera"
    core = False

    def __init__(self, settings: CameraSectionSettings, make_camera: Callable[[], Camera],
                 bus: Bus, driver: str) -> None:
        self.settings = settings
        self.make_camera = make_camera
        self.camera = make_camera()
        self.bus = bus
        self.driver = driver
        self.model = camera_model(settings)
        self.fps = settings.fps
        self.latest = LatestFrame()
        self.viewers = 0
        self.snapshot_waiters = 0
        self.cut_off = 0
        self.refused_viewers = 0
        self.unreachable: str | None = None
        self.frames = 0
        self.last_cost_ms = 0.0
        self._retry_s = RETRY_MIN_S
        self._wanted = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="camera")

    # -- demand ------------------------------------------------------------------------------

    def demand(self) -> int:
        """How many want frames now: viewers, snapshots, bus subscribers of the images."""
        return self.viewers + self.snapshot_waiters + self.bus.subscribers(CAMERA_IMAGE)

    def _want(self) -> None:
        self._wanted.set()

    # -- lifecycle ---------------------------------------------------------------------------

    async def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="camera")

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
        with contextlib.suppress(DeviceError):
            await self.camera.close()
        self._executor.shutdown(wait=False, cancel_futures=True)

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        idle_since: float | None = None
        next_frame = loop.time()
        while True:
            if self.demand() == 0:
                idle_since = loop.time() if idle_since is None else idle_since
                if self.camera.is_open and loop.time() - idle_since >= self.settings.idle_close_s:
                    await self._close()
                self._wanted.clear()
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(DEMAND_POLL_S):
                        await self._wanted.wait()
                next_frame = loop.time()
                continue
            idle_since = None
            if not self.camera.is_open and not await self._open():
                continue
            await asyncio.sleep(max(0.0, next_frame - loop.time()))
            next_frame = max(next_frame + 1.0 / self.fps, loop.time())
            await self._frame(loop)

    async def _open(self) -> bool:
        try:
            await self.camera.open()
        except DeviceError as exc:
            if self.unreachable != str(exc):
                log.error("camera: %s (trying again every %g..%g s)", exc, RETRY_MIN_S,
                          RETRY_MAX_S)
            self.unreachable = str(exc)
            await asyncio.sleep(self._retry_s)
            self._retry_s = min(2 * self._retry_s, RETRY_MAX_S)
            self.camera = self.make_camera()
            return False
        if self.unreachable is not None:
            log.info("camera: open again")
        self.unreachable, self._retry_s = None, RETRY_MIN_S
        return True

    async def _close(self) -> None:
        with contextlib.suppress(DeviceError):
            await self.camera.close()
        self.camera = self.make_camera()

    async def _frame(self, loop: asyncio.AbstractEventLoop) -> None:
        try:
            frame = await loop.run_in_executor(self._executor, self.camera.grab,
                                               max(2.0, 3.0 / self.fps))
        except DeviceError as exc:
            log.error("camera: %s", exc)
            self.unreachable = str(exc)
            await self._close()
            return
        self.frames += 1
        self.last_cost_ms = frame.cost_ms
        self.latest.put(frame)
        self.bus.publish(CAMERA_IMAGE, frame)
        self.bus.publish(CAMERA_INFO_KEY, self.info(frame.stamp, frame.width, frame.height))

    def info(self, stamp: float, width: int, height: int) -> CameraInfo:
        model = self.model
        scale = width / model.width  # a camera that gives another size than asked
        k = tuple(v * scale if i in (0, 2, 4, 5) else v
                  for i, v in enumerate(model.intrinsics()))
        return CameraInfo(stamp, self.settings.frame_id, width, height, k)

    def health(self) -> Health:
        values = {"driver": self.driver, "open": self.camera.is_open, "frames": self.frames,
                  "viewers": self.viewers, "watching": self.demand(),
                  "fps": self.fps, "last_frame_ms": round(self.last_cost_ms, 2),
                  "cut_off_viewers": self.cut_off, "refused_viewers": self.refused_viewers}
        if self.unreachable is not None:
            return Health("error", self.unreachable, values)
        return Health("ok", "" if self.demand() else "idle: nobody watching", values)

    # -- HTTP --------------------------------------------------------------------------------

    def routes(self) -> Sequence[Route]:
        return (Route("GET", "/api/camera", self.get_camera, "read"),
                Route("POST", "/api/camera", self.post_camera, "drive"),
                Route("GET", "/api/camera/snapshot", self.get_snapshot, "read"),
                Route("GET", "/api/camera/stream", self.get_stream, "read"))

    def state(self) -> dict[str, Any]:
        s = self.settings
        return {"driver": self.driver, "width": s.width, "height": s.height,
                "fps": self.fps, "max_fps": s.fps, "frame_id": s.frame_id,
                "hfov_deg": s.hfov_deg, "viewers": self.viewers, "watching": self.demand(),
                "open": self.camera.is_open, "frames": self.frames,
                "last_frame_ms": round(self.last_cost_ms, 2), "fault": self.unreachable,
                "intrinsics": self.model.intrinsics()}

    async def get_camera(self, request: web.Request) -> web.Response:
        return json_response(self.state())

    async def post_camera(self, request: web.Request) -> web.Response:
        body = await read_json_object(request, 1024)
        unknown = sorted(set(body) - {"fps"})
        if unknown:
            raise ApiError(422, f"{unknown[0]}: unknown field (fps)")
        if "fps" in body:
            fps = body["fps"]
            if isinstance(fps, bool) or not isinstance(fps, int | float) \
                    or not math.isfinite(fps) or not 0 < fps <= self.settings.fps:
                raise ApiError(422, f"fps: expected a number in (0, {self.settings.fps:g}] "
                               f"([camera] fps bounds it), got {fps!r}")
            self.fps = float(fps)
        return json_response(self.state())

    async def get_snapshot(self, request: web.Request) -> web.Response:
        frame = await self.snapshot()
        return web.Response(body=frame.jpeg, content_type="image/jpeg",
                            headers={"Cache-Control": "no-store",
                                     "X-Frame-Stamp": f"{frame.stamp:.6f}"})

    async def snapshot(self) -> Frame:
        """A fresh frame (the last one when it is younger than a frame period)."""
        latest = self.latest.frame
        if latest is not None and time.monotonic() - latest.t <= 1.0 / self.fps:
            return latest
        self.snapshot_waiters += 1
        self._want()
        try:
            got = await self.latest.next_after(self.latest.seq,
                                               self.settings.snapshot_timeout_s)
        finally:
            self.snapshot_waiters -= 1
        if got is None:
            raise ApiError(503, f"no camera frame within {self.settings.snapshot_timeout_s:g} s",
                           self.unreachable or "the camera is starting")
        return got[0]

    async def get_stream(self, request: web.Request) -> web.StreamResponse:
        if request.method == "HEAD":  # the headers a GET would get, and no frame
            return web.Response(headers={
                "Content-Type": f"multipart/x-mixed-replace; boundary={BOUNDARY}",
                "Cache-Control": "no-store"})
        if self.viewers >= self.settings.max_viewers:
            self.refused_viewers += 1
            raise ApiError(503, f"{self.viewers} viewers already ([camera] max_viewers)",
                           headers={"Retry-After": "5"})
        response = web.StreamResponse(headers={
            "Content-Type": f"multipart/x-mixed-replace; boundary={BOUNDARY}",
            "Cache-Control": "no-store", "X-Content-Type-Options": "nosniff"})
        self.viewers += 1
        self._want()
        try:
            _small_send_buffer(request)
            await response.prepare(request)
            await self._feed(request, response)
        except (ConnectionError, asyncio.CancelledError):
            pass  # the viewer went away
        finally:
            self.viewers -= 1
        return response

    async def _feed(self, request: web.Request, response: web.StreamResponse) -> None:
        """Newest frames to one viewer; a viewer that takes none for ``send_timeout_s`` is
        cut off, so it holds at most the frame being written and the socket's buffer."""
        seq, timeout = 0, self.settings.send_timeout_s
        while True:
            got = await self.latest.next_after(seq, 1.0)
            if request.transport is None or request.transport.is_closing():
                return
            if got is None:
                continue
            frame, seq = got
            try:
                async with asyncio.timeout(timeout):
                    await response.write(mjpeg_part(frame, BOUNDARY))
            except TimeoutError:
                self.cut_off += 1
                log.warning("camera: MJPEG viewer %s cut off: it took no frame for %g s "
                            "([camera] send_timeout_s)", request.remote, timeout)
                if request.transport is not None:
                    request.transport.abort()
                return

    # -- topics ------------------------------------------------------------------------------

    def topics(self) -> Sequence[Topic]:
        s = self.settings
        rate = f"{s.fps:g} Hz while subscribed"
        record = s.record_rate > 0
        frame_id = s.frame_id
        return (TopicOut("/camera/image_raw/compressed", COMPRESSED_IMAGE, CAMERA_IMAGE,
                         lambda frame: compressed_msg(frame, frame_id), rate, bulk=True,
                         state=True, record=record, record_rate=s.record_rate),
                TopicOut("/camera/camera_info", CAMERA_INFO, CAMERA_INFO_KEY,
                         camera_info_msg, "with each frame", record=record,
                         record_rate=s.record_rate))


#: the kernel's send buffer of an MJPEG viewer's socket (bytes; Linux doubles it): with
#: aiohttp's own 64 KiB, a viewer that stops reading holds about two frames of 640x480
VIEWER_SNDBUF = 32768


def _small_send_buffer(request: web.Request) -> None:
    sock = request.transport.get_extra_info("socket") if request.transport else None
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, VIEWER_SNDBUF)


def choose_driver(settings: CameraSectionSettings, sim: bool) -> str:
    """The driver ``auto`` means: sim under ``--sim``, else picamera2 when importable, else
    v4l2. ``--sim`` always uses the simulator's camera (it forces simulated hardware)."""
    if sim:
        return "sim"
    if settings.driver != "auto":
        return settings.driver
    import importlib.util

    return "picamera2" if importlib.util.find_spec("picamera2") is not None else "v4l2"


def camera_options(settings: CameraSectionSettings, config_section: dict[str, Any],
                   device: str) -> dict[str, Any]:
    from drivers.devices import device_class

    declared = device_class(device).OPTIONS
    return {k: v for k, v in config_section.items() if k in declared}


def create(ctx: DaemonContext) -> CameraComponent | None:
    settings = ctx.settings(CameraSectionSettings)
    if not settings.enabled:
        return None
    driver = choose_driver(settings, ctx.sim is not None)
    if driver == "sim" and ctx.sim is None:
        raise ValueError("[camera] driver = \"sim\" needs the simulator (arbiterd run --sim)")
    section = dict(ctx.config["camera"])
    model = camera_model(settings)
    make: Callable[[], Camera]
    if driver == "sim":
        from daemon.components.camera.sim_camera import SimCamera
        from drivers.camera import Camera as CameraBase

        assert ctx.sim is not None
        world = ctx.sim.world
        options = {k: v for k, v in section.items() if k in CameraBase.OPTIONS}
        make = lambda: SimCamera(options, section="camera", world=world,  # noqa: E731
                                 model=model, noise=settings.sim_noise)
    else:
        device = DRIVERS[driver]
        options = camera_options(settings, section, device)

        def make() -> Camera:
            camera = create_device(device, options, section="camera")
            assert isinstance(camera, Camera)
            return camera
    component = CameraComponent(settings, make, ctx.bus, driver)
    ctx.add_robot_info("camera", lambda: {"driver": driver, "width": settings.width,
                                          "height": settings.height,
                                          "frame_id": settings.frame_id})
    return component


COMPONENT = ComponentSpec("camera", create, CameraSectionSettings)
