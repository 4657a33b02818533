# The web console: a fixed table of static files served read-only at / on the HTTP port.
from __future__ import annotations

import gzip
import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from typing import TYPE_CHECKING

from aiohttp import web

from daemon.component import BaseComponent, ComponentSpec, DaemonContext, Route
from daemon.components.http.settings import HttpSettings
from daemon.components.rosbridge.settings import RosbridgeSettings

if TYPE_CHECKING:
    from daemon.web import Handler

# The console's files (in static/ beside this module): the page is served at /, every other
# one at /console/<name>. Nothing else is served: a request names an entry of this table or
# gets 404, so no path can reach another file (there is no directory walk).
PAGE = "index.html"
ASSETS = ("console.css", "icon.svg", "app.js", "api.js", "bridge.js", "drive.js",
          "joystick.js", "view.js", "hud.js", "health.js", "token.js", "robot.js", "log.js",
          "map.js", "navigate.js", "arm.js", "fetch.js", "battery.js")
FILES = (PAGE, *ASSETS)


def url_of(name: str) -> str:
    return "/" if name == PAGE else f"/console/{name}"


CONTENT_TYPES = {
    "html": "text/html; charset=utf-8",
    "css": "text/css; charset=utf-8",
    "js": "text/javascript; charset=utf-8",
    "svg": "image/svg+xml",
}


@dataclass(frozen=True)
class StaticFile:
    """One file of the console, loaded once at start: plain and gzip bodies, type, ETag."""

    body: bytes
    gzipped: bytes
    content_type: str
    etag: str


def load(name: str) -> StaticFile:
    body = resources.files(__package__).joinpath("static", name).read_bytes()
    digest = hashlib.sha256(body).hexdigest()[:16]
    return StaticFile(body, gzip.compress(body, 9, mtime=0),
                      CONTENT_TYPES[name.rsplit(".", 1)[1]], f'"{digest}"')


def none_match(fields: Sequence[str], etag: str) -> bool:
    """RFC 9110 If-None-Match: ``*`` matches any current representation; otherwise the list
    of entity tags is compared weakly (``W/"x"`` matches ``"x"``)."""
    tags = [tag.strip() for field in fields for tag in field.split(",")]
    return any(tag == "*" or tag.removeprefix("W/") == etag for tag in tags if tag)


def accepts_gzip(fields: Sequence[str]) -> bool:
    """RFC 9110 Accept-Encoding: gzip (or x-gzip) listed with a q-value above 0, or ``*``
    above 0 when gzip is not listed; ``gzip;q=0`` refuses it. A q-value that does not parse
    counts as 0 (the file is sent as it is, which every client takes)."""
    weights: dict[str, float] = {}
    for field in fields:
        for item in field.split(","):
            coding, _, params = item.partition(";")
            coding = coding.strip().lower()
            if coding:
                weights[coding] = _q_value(params)
    for name in ("gzip", "x-gzip"):
        if name in weights:
            return weights[name] > 0
    return weights.get("*", 0.0) > 0


def _q_value(params: str) -> float:
    for param in params.split(";"):
        key, _, value = param.partition("=")
        if key.strip().lower() == "q":
            try:
                q = float(value.strip())
            except ValueError:
                return 0.0
            return q if 0.0 <= q <= 1.0 else 0.0
    return 1.0


def content_security_policy(ws_port: int | None) -> str:
    """Only the console's own files run; it may talk to this host's HTTP and rosbridge ports."""
    sockets = f" ws://*:{ws_port} wss://*:{ws_port}" if ws_port else ""
    return ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; "
            f"connect-src 'self'{sockets}; base-uri 'none'; form-action 'none'; "
            "frame-ancestors 'none'")


class Console:
    """Serves the table of files with fixed, safe headers (CSP, nosniff, no framing)."""

    def __init__(self, ws_port: int | None) -> None:
        self.files = {name: load(name) for name in FILES}
        self.headers = {
            "Content-Security-Policy": content_security_policy(ws_port),
            "X-Content-Type-Options": "nosniff",
            "X-Frame-Options": "DENY",
            "Referrer-Policy": "no-referrer",
            "Cross-Origin-Opener-Policy": "same-origin",
            "Cache-Control": "no-cache",
            "Vary": "Accept-Encoding",
        }

    async def page(self, request: web.Request) -> web.StreamResponse:
        return self.answer(request, self.files[PAGE])

    async def asset(self, request: web.Request) -> web.StreamResponse:
        name = request.match_info["name"]
        if name not in ASSETS:
            raise web.HTTPNotFound()
        return self.answer(request, self.files[name])

    def answer(self, request: web.Request, static: StaticFile) -> web.StreamResponse:
        headers = {**self.headers, "ETag": static.etag}
        if none_match(request.headers.getall("If-None-Match", []), static.etag):
            return web.Response(status=304, headers=headers)
        headers["Content-Type"] = static.content_type
        body = static.body
        if accepts_gzip(request.headers.getall("Accept-Encoding", [])):
            body, headers["Content-Encoding"] = static.gzipped, "gzip"
        return web.Response(body=body, headers=headers)

    def routes(self) -> list[tuple[str, Handler]]:
        return [("/", self.page), ("/console/{name}", self.asset)]

    def sizes(self) -> tuple[int, int]:
        """Total bytes of the console as stored and as sent gzip-compressed."""
        return (sum(len(f.body) for f in self.files.values()),
                sum(len(f.gzipped) for f in self.files.values()))


class ConsoleComponent(BaseComponent):
    """The console as a component: two open routes (GET, and so HEAD), nothing to report."""

    name = "console"

    def __init__(self, console: Console) -> None:
        self.console = console

    def health(self) -> None:
        return None

    def routes(self) -> Sequence[Route]:
        return [Route("GET", path, handler, "open") for path, handler in self.console.routes()]


def create(ctx: DaemonContext) -> ConsoleComponent | None:
    """The console, unless ``[http] console = false``. Its routes are open to everyone: the
    page asks for the token itself, and holds nothing secret."""
    if not ctx.settings(HttpSettings).console:
        return None
    rosbridge = ctx.settings(RosbridgeSettings)
    return ConsoleComponent(Console(rosbridge.port if rosbridge.enabled else None))


COMPONENT = ComponentSpec("console", create)
