# HTTP endpoints of the control component: status, cmd_vel, e-stop, and the stall fault hook.
from __future__ import annotations

import time
from typing import Any

from aiohttp import web

from daemon.control.commands import CommandError, finite_number, parse_twist
from daemon.control.loop import ControlLoop
from daemon.http_api import ApiError, HttpServer, json_object, json_response

STAMP_FIELDS = ("id", "t_sent")


def parse_stamp(body: dict[str, Any], prefix: str = "") -> tuple[str | int | None, float | None]:
    """The optional ``id`` (string or integer) and ``t_sent`` (client wall clock, ms)."""
    cmd_id = body.get("id")
    if cmd_id is not None and (isinstance(cmd_id, bool) or not isinstance(cmd_id, str | int)):
        raise CommandError(f"{prefix}id: expected a string or integer")
    t_sent = body.get("t_sent")
    if t_sent is not None:
        t_sent = finite_number(t_sent, f"{prefix}t_sent")
    return cmd_id, t_sent


class ControlApi:
    """Registers the control endpoints on the HTTP server."""

    def __init__(self, control: ControlLoop, http: HttpServer,
                 allow_fault_injection: bool) -> None:
        self.control = control
        self.read_json = http.read_json
        self.read_json_body = http.read_json_body
        http.add_route("GET", "/api/status", self.get_status, access="read")
        http.add_route("POST", "/api/cmd_vel", self.post_cmd_vel, access="drive")
        http.add_route("POST", "/api/estop", self.post_estop, access="drive")
        if allow_fault_injection:
            http.add_route("POST", "/api/debug/stall", self.post_stall, access="drive")

    async def get_status(self, request: web.Request) -> web.Response:
        return json_response(self.control.status())

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
        if engaged:
            await self.control.engage_estop(reason)
        else:
            self.control.release_estop()
        return json_response({"engaged": self.control.arbiter.estop_engaged})

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
