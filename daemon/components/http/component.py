# HTTP API server (aiohttp): routes declare who may call them; one guard enforces it; JSON errors.
from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import struct
from collections.abc import Mapping, Sequence
from typing import Any, BinaryIO

from aiohttp import HttpVersion10, web
from aiohttp.web_urldispatcher import AbstractRoute

from base.config import Config
from daemon.component import ComponentSpec, DaemonContext, Route
from daemon.components.http.conn import (
    AcceptErrorFilter,
    CappedRunner,
    LogLimiter,
    bad_request_log,
)
from daemon.components.http.settings import HttpSettings
from daemon.health import Health
from daemon.listen import Listener, start_listening
from daemon.security import Security
from daemon.topics import ACCESS_LEVELS, Access, Topic
from daemon.web import (
    REFUSED,
    ApiError,
    Handler,
    error_response,
    json_object,
    read_json_body,
)

log = logging.getLogger("arbiterd.http")

#: on stop, how long a request in progress (a download to a reader that stalls) may go on
#: before it is cancelled; its connection is closed after as long again at most
SHUTDOWN_GRACE_S = 1.0
#: a download goes out in pieces of this size, each within [http] send_timeout_s
SEND_CHUNK = 65536
#: what a connection let in beyond the cap (every other one busy) may still ask for
PRIORITY_ROUTES = frozenset({("POST", "/api/estop"), ("GET", "/api/health"),
                             ("HEAD", "/api/health")})

slow_reader_log = LogLimiter(log, "slow-reader", burst=5, window_s=10.0)

internal_error_log = LogLimiter(log, "internal-error", burst=2, window_s=60.0)


@web.middleware
async def _errors(request: web.Request, handler: Handler) -> web.StreamResponse:
    try:
        return await handler(request)
    except ApiError as exc:
        if exc.status == REFUSED:  # a valid request the robot says no to now: not a bad one
            log.debug("refused %s %s from %s: %s", request.method, request.path[:100],
                      request.remote, exc.message)
        else:
            _log_bad_request(request, exc.status, exc.message)
        return error_response(exc.status, exc.message, exc.detail, exc.headers)
    except web.HTTPException as exc:
        if exc.status < 400:
            raise
        return _http_exception(request, exc)
    except Exception:
        internal_error_log(logging.ERROR, "%s %s failed", request.method, request.path,
                           exc_info=True)
        return error_response(500, "internal error", "see the daemon log")


def _http_exception(request: web.Request, exc: web.HTTPException) -> web.Response:
    """aiohttp's 404/405/413 as the documented JSON error; 405 keeps its ``Allow``."""
    _log_bad_request(request, exc.status, exc.reason)
    allow = exc.headers.get("Allow")
    if allow is not None:
        return error_response(exc.status, exc.reason, f"allowed: {allow}", {"Allow": allow})
    return error_response(exc.status, exc.reason, None)


async def _answer_headers(request: web.Request, response: web.StreamResponse) -> None:
    """Every answer: no content sniffing; API answers (and every error) are not cached."""
    response.headers.setdefault("X-Content-Type-Options", "nosniff")
    if request.path.startswith("/api/") or request.path == "/metrics" or response.status >= 400:
        response.headers.setdefault("Cache-Control", "no-store")


def _log_bad_request(request: web.Request, status: int, message: str) -> None:
    bad_request_log(logging.WARNING, "bad HTTP request from %s: %s %s -> %d %s",
                    request.remote, request.method, request.path[:100], status, message)


class Guard:
    """The one place that decides who may call a route: the Host allow-list for every
    request, then the route's declared access (open, stop, read, drive): for stop and drive
    routes the browser Origin, for drive routes (and read routes with
    ``read_requires_token``) the token. A handler whose body decides the access (the e-stop)
    asks :meth:`authorize` again once it has read it."""

    def __init__(self, security: Security) -> None:
        self.security = security
        self.access: dict[AbstractRoute, Access] = {}

    @web.middleware
    async def middleware(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        if request.version < HttpVersion10:  # no headers, no Host: nothing to check
            raise ApiError(400, "malformed HTTP request", "HTTP/0.9 is not supported: send "
                           "HTTP/1.0 or HTTP/1.1")
        if getattr(request.protocol, "priority_only", False) and (
                request.method, request.path) not in PRIORITY_ROUTES:
            request.protocol.force_close()
            raise ApiError(503, "the HTTP server is at its connection limit",
                           "this connection may only reach POST /api/estop and GET "
                           "/api/health; [http] max_connections and reserved_connections "
                           "set the limits")
        host = request.headers.get("Host")
        if not self.security.host_ok(host):
            raise ApiError(403, f"unknown Host {host!r}", "this daemon answers only to its IP "
                           "addresses, localhost and its own names; add the name to "
                           "[security] allowed_hosts if it is yours")
        if request.match_info.http_exception is None:  # 404 and 405 need no authority
            self.check(self.access.get(request.match_info.route, "drive"), request, host)
        return await handler(request)

    def check(self, access: Access, request: web.Request, host: str | None) -> None:
        if access == "open":
            return
        if access in ("stop", "drive"):
            origin = request.headers.get("Origin")
            if not self.security.origin_ok(origin, host):
                raise ApiError(403, f"Origin {origin!r} may not "
                               f"{'stop' if access == 'stop' else 'drive'} this robot",
                               "a web page from another site sent this request; add the "
                               "origin to [security] allowed_origins if it is yours")
        needs_token = access == "drive" or (access == "read" and
                                            self.security.read_requires_token)
        if not needs_token:
            return
        token = self.security.check_token(request.headers, request.query, request.remote)
        if token == "guessing":
            raise ApiError(429, "too many wrong tokens from this address",
                           "wrong tokens from it are refused for a while; wait a second",
                           {"Retry-After": "1"})
        if token != "ok":
            raise ApiError(401, "a valid bearer token is required",
                           "send 'Authorization: Bearer <token>'",
                           {"WWW-Authenticate": 'Bearer realm="arbiterd"'})

    def authorize(self, access: Access, request: web.Request) -> None:
        """:meth:`check` from inside a handler (the Host was checked on the way in)."""
        self.check(access, request, request.headers.get("Host"))


def reset(transport: asyncio.Transport | None) -> None:
    """Close a connection at once with a reset, dropping what is still queued for it (a plain
    close would leave the kernel sending it to a client that reads nothing, for minutes)."""
    if transport is None:
        return
    sock = transport.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    transport.abort()


# -- the server ----------------------------------------------------------------------------

class HttpServer:
    """The ``:8085`` server; a component (``http``) other components add routes to."""

    name = "http"
    core = True

    def __init__(self, options: HttpSettings, security: Security) -> None:
        self.host = options.host
        self.port = options.port
        self.max_body_bytes = options.max_body_bytes
        self.body_timeout_s = options.body_timeout_s
        self.idle_timeout_s = options.idle_timeout_s
        self.max_connections = options.max_connections
        self.reserved_connections = options.reserved_connections
        self.send_timeout_s = options.send_timeout_s
        self.guard = Guard(security)
        self.app = web.Application(middlewares=[_errors, self.guard.middleware],
                                   client_max_size=self.max_body_bytes)
        self.app.on_response_prepare.append(_answer_headers)
        self._runner: CappedRunner | None = None
        self._accept_errors: AcceptErrorFilter | None = None
        self.bound_port: int | None = None

    def add_route(self, method: str, path: str, handler: Handler, *,
                  access: Access = "drive") -> None:
        """Serve ``method path``; ``access`` says who may call it: ``open`` (anyone who passes
        the Host check), ``stop`` (a browser Origin of this host, never a token), ``read`` (the
        token too when ``read_requires_token``) or ``drive`` (the token when one is configured,
        and a browser Origin of this host). A GET route answers HEAD too."""
        if access not in ACCESS_LEVELS:
            raise ValueError(f"{method} {path}: access must be one of {ACCESS_LEVELS}, "
                             f"got {access!r}")
        methods = [method, "HEAD"] if method == "GET" else [method]
        for verb in methods:
            self.guard.access[self.app.router.add_route(verb, path, handler)] = access

    def access_table(self) -> list[tuple[str, str, Access]]:
        """(method, path, access) of every route, in registration order."""
        return [(route.method, route.resource.canonical if route.resource else "", access)
                for route, access in self.guard.access.items()]

    def authorize(self, access: Access, request: web.Request) -> None:
        """:meth:`Guard.authorize`: from inside a handler, check the caller's access."""
        self.guard.authorize(access, request)

    async def read_json(self, request: web.Request) -> dict[str, Any]:
        """The body as a JSON object within this server's size and time limits."""
        return json_object(await self.read_json_body(request))

    async def read_json_body(self, request: web.Request) -> bytes:
        """The raw JSON body within this server's size and time limits."""
        return await read_json_body(request, self.max_body_bytes, self.body_timeout_s)

    async def send_file(self, request: web.Request, file: BinaryIO, size: int,
                        headers: Mapping[str, str]) -> web.StreamResponse:
        """Stream an open file as the answer, ``SEND_CHUNK`` at a time; a client that takes
        no piece for ``send_timeout_s`` is cut off (it would hold a connection slot, and the
        daemon's shutdown, for as long as it pleases)."""
        response = web.StreamResponse(headers=headers)
        response.content_length = size
        await response.prepare(request)
        if request.method == "HEAD":
            return response
        sent = 0
        while chunk := await asyncio.to_thread(file.read, SEND_CHUNK):
            try:
                async with asyncio.timeout(self.send_timeout_s):
                    await response.write(chunk)
            except TimeoutError:
                slow_reader_log(logging.WARNING, "HTTP answer to %s closed: it made no progress "
                                "for %g s (%d of %d bytes sent); [http] send_timeout_s sets the "
                                "limit", request.remote, self.send_timeout_s, sent, size)
                reset(request.transport)
                request.protocol.force_close()
                return response  # aiohttp finds the connection gone and lets it be
            except ConnectionError:
                return response  # the client went away: nothing to say, nobody to say it to
            sent += len(chunk)
        return response

    async def start(self) -> None:
        self._accept_errors = AcceptErrorFilter(asyncio.get_running_loop())
        self._accept_errors.install()
        self._runner = CappedRunner(self.app, self.max_connections,
                                    reserved=self.reserved_connections, access_log=None,
                                    send_timeout_s=self.send_timeout_s,
                                    handle_signals=False, keepalive_timeout=self.idle_timeout_s,
                                    shutdown_timeout=SHUTDOWN_GRACE_S)
        self.bound_port = await start_listening(self._runner,
                                                 Listener("http", self.host, self.port))
        log.info("HTTP API on http://%s:%s", self.host, self.bound_port)

    async def stop(self) -> None:
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
        if self._accept_errors is not None:
            self._accept_errors.uninstall()

    def routes(self) -> Sequence[Route]:
        return ()

    def topics(self) -> Sequence[Topic]:
        return ()

    def health(self) -> Health:
        running = self._runner is not None
        server = self._runner.server if self._runner else None
        values = {"port": self.bound_port,
                  "connections": len(server.connections) if server else 0,
                  "connections_refused": getattr(server, "refused", 0),
                  "accept_errors": self._accept_errors.count if self._accept_errors else 0}
        return Health("ok", values=values) if running else \
            Health("error", "not listening", values)


def create(ctx: DaemonContext) -> HttpServer | None:
    """The server every route is added to (built first, started last, stopped first)."""
    if not isinstance(ctx.http, HttpServer):
        raise TypeError(f"ctx.http is a {type(ctx.http).__name__}, not the HttpServer it serves")
    return ctx.http if ctx.settings(HttpSettings).enabled else None


def listens(config: Config) -> list[Listener]:
    http = config.get(HttpSettings)
    return [Listener("http", http.host, http.port)] if http.enabled else []


COMPONENT = ComponentSpec("http", create, HttpSettings, listens=listens)
