# `arbiterd fleet`: the Zenoh router, the roster of robots and the fleet page's HTTP API.
from __future__ import annotations

import asyncio
import json
import logging
from importlib import resources
from pathlib import Path
from typing import Any

from aiohttp import web

from base.config import Config
from daemon.components.fleet import keys
from daemon.components.fleet.roster import Roster
from daemon.components.fleet.settings import FleetSettings
from daemon.components.fleet.zconfig import router_config
from daemon.components.http.component import HttpServer
from daemon.components.http.settings import HttpSettings
from daemon.messages import cdr
from daemon.messages.definitions import BOOL
from daemon.security import Security
from daemon.settings import SecuritySettings
from daemon.web import ApiError, json_response

log = logging.getLogger("arbiterd.fleet")

#: how often the operator asks every robot for its status (e-stop, health), s
STATUS_PERIOD_S = 1.0
#: how long a command waits for the robots' replies, s
COMMAND_TIMEOUT_S = 2.0
PAGES = {"/": ("index.html", "text/html"), "/fleet.js": ("fleet.js", "text/javascript")}


class FleetOperator:
    """The router (other robots' and operators' sessions meet here), the roster it feeds,
    and the HTTP server of the fleet page (the robot's Host, Origin and token rules)."""

    def __init__(self, config: Config, listen: str | None = None,
                 http_port: int | None = None) -> None:
        s = config.get(FleetSettings)
        self.settings = s
        self.listen = listen or s.operator_listen
        users = Path(s.operator_users_file) if s.operator_users_file else None
        self.zconfig = router_config(self.listen, users, list(s.operator_operators))
        sec = config.get(SecuritySettings)
        security = Security(config.token, sec.allowed_origins, sec.read_requires_token,
                            sec.allowed_hosts)
        http = HttpSettings(host=s.operator_http_host,
                            port=http_port if http_port is not None else s.operator_http_port)
        self.http = HttpServer(http, security)
        self.roster = Roster()
        self.session: Any = None
        self._declared: list[Any] = []
        self._poller: asyncio.Task[None] | None = None
        self._routes()

    def _routes(self) -> None:
        add = self.http.add_route
        for path in PAGES:
            add("GET", path, self.get_page, access="open")
        add("GET", "/api/robots", self.get_robots, access="read")
        add("POST", "/api/stop_all", self.post_stop_all, access="stop")
        add("POST", "/api/robots/{robot_id}/estop", self.post_estop, access="stop")

    # -- lifecycle --------------------------------------------------------------------------------

    async def start(self) -> None:
        self.session = await asyncio.to_thread(_open, self.zconfig)
        roster = self.roster
        self._declared.append(self.session.liveliness().declare_subscriber(
            keys.robot_key("*", keys.ALIVE),
            lambda s: roster.on_alive(str(s.key_expr), _is_put(s)), history=True))
        for name in ("odom", "pose", "battery_state", keys.INFO):
            self._declared.append(self.session.declare_subscriber(
                keys.robot_key("*", name),
                lambda s: roster.on_sample(str(s.key_expr), s.payload.to_bytes())))
        self._poller = asyncio.create_task(self._poll_status())
        await self.http.start()
        log.info("fleet: router on %s (%s), fleet page on http://%s:%s/", self.listen,
                 "user-password authentication" if "transport" in self.zconfig
                 else "NO authentication: robots accept no command", self.http.host,
                 self.http.bound_port)

    async def stop(self) -> None:
        if self._poller is not None:
            self._poller.cancel()
        await self.http.stop()
        if self.session is not None:
            await asyncio.to_thread(self.session.close)
            self.session = None

    async def _poll_status(self) -> None:
        while True:
            replies = await asyncio.to_thread(_query, self.session,
                                              keys.robot_key("*", keys.SERVICE, "status"),
                                              None, COMMAND_TIMEOUT_S)
            for key, ok, payload in replies:
                where = keys.split(key)
                if ok and where is not None:
                    try:
                        status = json.loads(payload)
                    except ValueError:
                        continue
                    if isinstance(status, dict):
                        self.roster.on_status(where[0], status)
            await asyncio.sleep(STATUS_PERIOD_S)

    # -- HTTP -------------------------------------------------------------------------------------

    async def get_page(self, request: web.Request) -> web.Response:
        name, content_type = PAGES[request.path]
        body = resources.files(__package__).joinpath("static", name).read_bytes()
        return web.Response(body=body, content_type=content_type,
                            headers={"Cache-Control": "no-cache"})

    async def get_robots(self, request: web.Request) -> web.Response:
        return json_response(self.roster.snapshot(self.settings.operator_stale_s))

    async def post_stop_all(self, request: web.Request) -> web.Response:
        return json_response(await self.estop("*", True))

    async def post_estop(self, request: web.Request) -> web.Response:
        robot_id = request.match_info["robot_id"]
        if not keys_ok(robot_id):
            raise ApiError(400, "robot_id: letters, digits, _ and - only")
        body = await self.http.read_json(request)
        engaged = body.get("engaged", True)
        if not isinstance(engaged, bool):
            raise ApiError(422, "engaged: expected true or false")
        if not engaged:
            self.http.authorize("drive", request)  # releasing is a driving command
        answer = await self.estop(robot_id, engaged)
        if not answer["stopped"] and not answer["errors"]:
            raise ApiError(404, f"robot {robot_id!r} did not answer",
                           "see GET /api/robots")
        return json_response(answer)

    async def estop(self, robot_id: str, engaged: bool) -> dict[str, Any]:
        """Latch (or release) the e-stop of one robot or, with ``*``, of every robot; which
        robots confirmed, which refused and why, and which online robots stayed silent."""
        payload = cdr.encode(BOOL, {"data": engaged})
        replies = await asyncio.to_thread(_query, self.session,
                                          keys.command_key(robot_id, "/estop"), payload,
                                          COMMAND_TIMEOUT_S)
        done: list[str] = []
        errors: dict[str, str] = {}
        for key, ok, body in replies:
            rid = _reply_robot(key, body)
            if ok:
                done.append(rid)
            else:
                errors[rid] = _error_text(body)
        expected = self.roster.online() if robot_id == "*" else [robot_id]
        silent = [r for r in expected if r not in done and r not in errors]
        log.warning("fleet: e-stop %s for %s: %d confirmed, %d refused, %d silent",
                    "latched" if engaged else "released", "every robot" if robot_id == "*"
                    else robot_id, len(done), len(errors), len(silent))
        return {"engaged": engaged, "stopped": sorted(done), "errors": errors,
                "silent": silent}

    @property
    def bound_port(self) -> int | None:
        return self.http.bound_port


def keys_ok(robot_id: str) -> bool:
    from daemon.components.fleet.settings import ROBOT_ID

    return bool(ROBOT_ID.match(robot_id))


def _open(config: dict[str, Any]) -> Any:
    import zenoh

    return zenoh.open(zenoh.Config.from_json5(json.dumps(config)))


def _is_put(sample: Any) -> bool:
    import zenoh

    return bool(sample.kind == zenoh.SampleKind.PUT)


def _query(session: Any, key: str, payload: bytes | None,
           timeout_s: float) -> list[tuple[str, bool, bytes]]:
    """Every reply to one query: (key, ok, payload); an error reply has no key of its own."""
    out = []
    for reply in session.get(key, payload=payload, timeout=timeout_s):
        if reply.ok is not None:
            out.append((str(reply.ok.key_expr), True, reply.ok.payload.to_bytes()))
        else:
            out.append(("", False, reply.err.payload.to_bytes()))
    return out


def _reply_robot(key: str, body: bytes) -> str:
    where = keys.split(key)
    if where is not None:
        return where[0]
    try:
        return str(json.loads(body).get("robot_id", "?"))
    except (ValueError, AttributeError):
        return "?"


def _error_text(body: bytes) -> str:
    try:
        return str(json.loads(body).get("error", ""))[:300]
    except (ValueError, AttributeError):
        return body[:300].decode(errors="replace")


async def serve(config: Config, listen: str | None, http_port: int | None) -> int:
    """Run the operator until interrupted."""
    operator = FleetOperator(config, listen, http_port)
    await operator.start()
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await stop.wait()
    finally:
        await operator.stop()
    return 0
