# The "control" component: the control loop's lifecycle, its HTTP endpoints and its topics.
from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import orjson
from aiohttp import web

from daemon.commands import (
    STAMP_FIELDS,
    CommandError,
    Twist,
    finite_number,
    parse_pose,
    parse_stamp,
    parse_twist,
    plain_stamped,
)
from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Plugs, Route
from daemon.components.control.estop import LATCH, LatchLimit, estop_access
from daemon.components.control.loop import Applied, ControlLoop
from daemon.health import Health
from daemon.messages.convert import command_msg, latency_msg, odometry_msg, tf_msg
from daemon.messages.definitions import (
    BOOL,
    COMMAND,
    ODOMETRY,
    STRING,
    TF_MESSAGE,
    TWIST,
    TWIST_STAMPED,
)
from daemon.security import Security, hide_paths
from daemon.settings import ControlSettings
from daemon.telemetry import COMMAND as COMMAND_KEY
from daemon.telemetry import LATENCY_REPORT, ODOM, TRANSFORMS, Transform
from daemon.topics import Inbound, Refusal, Topic, TopicIn, TopicOut
from daemon.web import ApiError, HttpPort, json_object, json_response


class ControlComponent(BaseComponent):
    """The control loop as a component (``control``, core): it starts and stops the loop,
    serves status, cmd_vel and the e-stop over HTTP, and declares the command topics and the
    odometry it publishes."""

    name = "control"
    core = True

    def __init__(self, control: ControlLoop, http: HttpPort, settings: ControlSettings,
                 security: Security | None = None, plugs: Plugs | None = None) -> None:
        self.control = control
        self.settings = settings
        self.security = security or Security("")
        self.read_json = http.read_json
        self.read_json_body = http.read_json_body
        self.authorize = http.authorize
        self.latches = LatchLimit()
        if settings.enable_odom_tf and plugs is not None:
            bus = plugs.bus
            plugs.subscribe(ODOM, lambda sample: bus.publish(
                TRANSFORMS, (Transform.of_odometry(sample),)))

    async def start(self) -> None:
        await self.control.start()

    async def stop(self) -> None:
        await self.control.stop()

    def health(self) -> Health:
        report = self.control.health()
        if report["fault"]:
            problem = f"driver fault: {report['fault']}"
        elif report["stalled"]:
            problem = "stall stop: the control tick ran late, the wheels were zeroed"
        elif report["wheel_guard"]["tripped"]:
            problem = f"wheel guard: {report['wheel_guard']['tripped']}"
        else:
            problem = ""
        return Health.of(report, otherwise=problem)

    def routes(self) -> Sequence[Route]:
        routes = [Route("GET", "/api/status", self.get_status, "read"),
                  Route("POST", "/api/cmd_vel", self.post_cmd_vel, "drive"),
                  Route("POST", "/api/estop", self.post_estop, LATCH),
                  Route("POST", "/api/odom/reset", self.post_odom_reset, "drive")]
        if self.settings.allow_fault_injection:
            routes.append(Route("POST", "/api/debug/stall", self.post_stall, "drive"))
        return routes

    def topics(self) -> Sequence[Topic]:
        topics: list[Topic] = [
            TopicIn("/cmd_vel", TWIST, self.on_cmd_vel, "drive", (TWIST, TWIST_STAMPED),
                    moves=True),
            TopicIn("/stamped_cmd_vel", STRING, self.on_stamped_cmd_vel, "drive", moves=True),
            TopicIn("/estop", BOOL, self.on_estop, LATCH, moves=True,
                    access_for=lambda msg: estop_access(msg["data"])),
            TopicOut("/odom", ODOMETRY, ODOM, odometry_msg, "20 Hz"),
            TopicOut("/latency_reports", STRING, LATENCY_REPORT, latency_msg, "per command",
                     state=False),
            TopicOut("/commands", COMMAND, COMMAND_KEY, command_msg, "per command",
                     bridge=False, state=False),
            # odom -> base_link at the odometry rate ([control] enable_odom_tf), and what other
            # components add (the mapper's map -> odom)
            TopicOut("/tf", TF_MESSAGE, TRANSFORMS, tf_msg, "20 Hz", state=False),
        ]
        return topics

    # -- topics ------------------------------------------------------------------------------

    async def on_cmd_vel(self, message: Inbound) -> Refusal | None:
        """``/cmd_vel``: a Twist, or a TwistStamped."""
        try:
            if message.type == TWIST_STAMPED:
                twist = parse_twist(message.msg["twist"], prefix="twist.")
            else:
                twist = parse_twist(message.msg)
        except CommandError as exc:
            return Refusal(f"msg.{exc}; not applied")
        applied = await self.control.submit(message.source, twist, t_recv=message.t_recv,
                                            priority=message.priority,
                                            timeout_s=message.timeout_s)
        return None if applied.accepted else _refused(applied)

    async def on_stamped_cmd_vel(self, message: Inbound) -> Refusal | None:
        """``/stamped_cmd_vel``: a std_msgs/String of JSON ``{linear, angular, id, t_sent}``."""
        try:
            try:
                body = orjson.loads(message.msg["data"])  # refuses NaN, Infinity, overflow
            except ValueError as exc:
                raise CommandError(f"data: not a JSON command: {exc}") from None
            plain = plain_stamped(body)  # the common shape in one pass; else the general one
            if plain is not None:
                twist, cmd_id, t_sent = plain
            else:
                twist, cmd_id, t_sent = _parse_stamped(body)
        except CommandError as exc:
            return Refusal(f"msg.{exc}; not applied")
        # the control loop's call without a layer between: this runs for every command
        applied = await self.control.submit(message.source, twist, t_recv=message.t_recv,
                                            cmd_id=cmd_id, t_sent_ms=t_sent,
                                            priority=message.priority,
                                            timeout_s=message.timeout_s)
        return None if applied.accepted else _refused(applied)

    async def on_estop(self, message: Inbound) -> Refusal | None:
        """``/estop``: std_msgs/Bool, true latches, false releases (rosbridge checked the
        access :func:`estop_access` asks for)."""
        refused = await self._set_estop(message.msg["data"], "rosbridge /estop",
                                        message.sender, message.peer)
        return Refusal(refused[1], repeats=True) if refused else None

    async def _set_estop(self, engaged: bool, reason: str, by: str,
                         peer: str) -> tuple[int, str] | None:
        """Latch or release for ``by`` (whose access was checked); why not, with its HTTP
        status: a release once the daemon is shutting down (409), a latch over its peer's
        rate while the e-stop is already engaged (429; a latch that stops the robot is never
        refused)."""
        if not engaged:
            refusal = self.control.release_estop(by)
            return (409, f"e-stop not released: {refusal}") if refusal else None
        if not self.latches.allow(peer) and self.control.arbiter.estop_engaged:
            return (429, f"e-stop already engaged; {peer} latched it more than "
                    f"{self.latches.burst} times in {self.latches.window_s:g} s")
        await self.control.engage_estop(reason, by)
        return None

    # -- HTTP --------------------------------------------------------------------------------

    async def get_status(self, request: web.Request) -> web.Response:
        status = self.control.status()
        if not self.security.sees_paths(request.headers, request.query,
                                        request.remote):
            status = hide_paths(status)  # a fault naming a device node
        return json_response(status)

    async def post_cmd_vel(self, request: web.Request) -> web.Response:
        raw = await self.read_json_body(request)
        t_recv = time.monotonic()  # received: the whole body is here (a slow client is not us)
        body = json_object(raw)
        try:
            twist = parse_twist(body, extra=STAMP_FIELDS)
            cmd_id, t_sent = parse_stamp(body)
        except CommandError as exc:
            raise ApiError(422, f"invalid command: {exc}") from None
        applied = await self.control.submit("http", twist, t_recv=t_recv, cmd_id=cmd_id,
                                            t_sent_ms=t_sent)
        if not applied.accepted:
            raise ApiError(409, f"command refused: {applied.error}")
        return json_response({
            "accepted": True, "id": cmd_id, "clamped": applied.clamped,
            "wheel_speeds_rad_s": list(applied.wheel_rad_s),
            "exec_ms": applied.report.exec_ms if applied.report else None,
            "safety": applied.guard_action,
        })

    async def post_estop(self, request: web.Request) -> web.Response:
        body = await self.read_json(request)
        unknown = sorted(set(body) - {"engaged", "reason"})
        if unknown:
            raise ApiError(422, f"invalid e-stop request: {unknown[0]}: unknown field")
        engaged = body.get("engaged")
        if not isinstance(engaged, bool):
            raise ApiError(422, "invalid e-stop request: engaged: expected true or false")
        reason = body.get("reason", "http")
        if not isinstance(reason, str):
            raise ApiError(422, "invalid e-stop request: reason: expected a string")
        self.authorize(estop_access(engaged), request)  # releasing needs the token
        peer = request.remote or "?"
        refused = await self._set_estop(engaged, reason, f"HTTP {peer}", peer)
        if refused:
            status, text = refused
            raise ApiError(status, text, None, {"Retry-After": "1"} if status == 429 else None)
        return json_response({"engaged": self.control.arbiter.estop_engaged})

    async def post_odom_reset(self, request: web.Request) -> web.Response:
        """Odometry reports ``{"x", "y", "theta"}`` (each optional, 0) where the robot is now."""
        body = await self.read_json(request) if request.can_read_body else {}
        try:
            pose = parse_pose(body) or (0.0, 0.0, 0.0)
        except CommandError as exc:
            raise ApiError(422, f"invalid pose: {exc}") from None
        self.control.reset_odometry(*pose, by=f"HTTP {request.remote or '?'}")
        return json_response({"pose": self.control.status()["pose"]})

    async def post_stall(self, request: web.Request) -> web.Response:
        """Block the event loop on purpose (fault injection for watchdog tests)."""
        body = await self.read_json(request)
        try:
            seconds = finite_number(body.get("seconds"), "seconds")
        except CommandError as exc:
            raise ApiError(422, str(exc)) from None
        if not 0 < seconds <= 30:
            raise ApiError(422, "seconds: must be in (0, 30]")
        time.sleep(seconds)  # noqa: ASYNC251 - the stall is the point
        return json_response({"stalled_s": seconds})


def _parse_stamped(body: Any) -> tuple[Twist, str | int | None, float | None]:
    """A stamped command's body, every field checked (CommandError naming ``data.<field>``)."""
    if not isinstance(body, dict):
        raise CommandError("data: expected a JSON object")
    twist = parse_twist(body, extra=STAMP_FIELDS, prefix="data.")
    cmd_id, t_sent = parse_stamp(body, "data.")
    return twist, cmd_id, t_sent


def _refused(applied: Applied) -> Refusal:
    return Refusal(f"command refused: {applied.error or 'command not applied'}", repeats=True)


def create(ctx: DaemonContext) -> ControlComponent:
    if not isinstance(ctx.robot, ControlLoop):
        raise TypeError(f"ctx.robot is a {type(ctx.robot).__name__}, not the ControlLoop it runs")
    return ControlComponent(ctx.robot, ctx.http, ctx.settings(ControlSettings), ctx.security,
                            ctx.plugs)


COMPONENT = ComponentSpec("control", create, ControlSettings)
