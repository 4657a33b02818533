# The web console: a fixed table of static files served read-only at / on the HTTP port.
from __future__ import annotations

import gzip
import hashlib
from dataclasses import dataclass
from importlib import resources
from typing import TYPE_CHECKING

from aiohttp import web

if TYPE_CHECKING:
    from daemon.config import Config
    from daemon.http_api import HttpServer

# URL path => file in daemon/console/static/. Nothing else is served: no directory walk, so no
# request can name a file of its own.
FILES: dict[str, str] = {
    "/": "index.html",
    "/console/console.css": "console.css",
    "/console/icon.svg": "icon.svg",
    "/console/app.js": "app.js",
    "/console/api.js": "api.js",
    "/console/bridge.js": "bridge.js",
    "/console/drive.js": "drive.js",
    "/console/joystick.js": "joystick.js",
    "/console/view.js": "view.js",
    "/console/hud.js": "hud.js",
    "/console/health.js": "health.js",
    "/console/token.js": "token.js",
}

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


def content_security_policy(ws_port: int | None) -> str:
    """Only the console's own files run; it may talk to this host's HTTP and rosbridge ports."""
    sockets = f" ws://*:{ws_port} wss://*:{ws_port}" if ws_port else ""
    return ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; "
            f"connect-src 'self'{sockets}; base-uri 'none'; form-action 'none'; "
            "frame-ancestors 'none'")


class Console:
    """Serves the table of files with fixed, safe headers (CSP, nosniff, no framing)."""

    def __init__(self, ws_port: int | None) -> None:
        self.files = {path: load(name) for path, name in FILES.items()}
        self.headers = {
            "Content-Security-Policy": content_security_policy(ws_port),
            "X-Content-Type-Options": "nosniff",
            "X-Frame-Options": "DENY",
            "Referrer-Policy": "no-referrer",
            "Cross-Origin-Opener-Policy": "same-origin",
            "Cache-Control": "no-cache",
            "Vary": "Accept-Encoding",
        }

    async def handle(self, request: web.Request) -> web.StreamResponse:
        static = self.files[request.path]
        headers = {**self.headers, "ETag": static.etag}
        if static.etag in request.headers.get("If-None-Match", ""):
            return web.Response(status=304, headers=headers)
        headers["Content-Type"] = static.content_type
        body = static.body
        if "gzip" in request.headers.get("Accept-Encoding", ""):
            body, headers["Content-Encoding"] = static.gzipped, "gzip"
        return web.Response(body=body, headers=headers)

    def sizes(self) -> tuple[int, int]:
        """Total bytes of the console as stored and as sent gzip-compressed."""
        return (sum(len(f.body) for f in self.files.values()),
                sum(len(f.gzipped) for f in self.files.values()))


def register(http: HttpServer, config: Config) -> Console:
    """Adds the console's routes (GET, and so HEAD), open to everyone: the page asks for the
    token itself, and holds nothing secret."""
    rosbridge = config["rosbridge"]
    console = Console(rosbridge["port"] if rosbridge["enabled"] else None)
    for path in FILES:
        http.add_route("GET", path, console.handle, access="open")
    return console
