# HTTP API server (aiohttp): routes declare who may call them; one guard enforces it; JSON errors.
from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import socket
import struct
from collections.abc import Awaitable, Callable, Mapping, Sequence
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
    one_line,
)
from daemon.components.http.settings import HttpSettings
from daemon.listen import Listener, start_listening
from daemon.messages.convert import to_json
from daemon.security import Security
from daemon.topics import ACCESS_LEVELS, Access, Topic

log = logging.getLogger("arbiterd.http")

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]
#: a valid request the robot refuses in its present state (e-stop latched, driver fault)
REFUSED = 409
MAX_JSON_DEPTH = 32
MAX_INT_DIGITS = 64
READ_CHUNK = 65536
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


class ApiError(Exception):
    """An error answered as ``{"error": message, "detail": detail}`` with ``status``."""

    def __init__(self, status: int, message: str, detail: Any = None,
                 headers: Mapping[str, str] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.message = message
        self.detail = detail
        self.headers = dict(headers or {})


def json_response(data: Any, status: int = 200) -> web.Response:
    return web.json_response(data, status=status, dumps=_dumps)


def _dumps(data: Any) -> str:
    return json.dumps(data, allow_nan=False, default=to_json)


def error_response(status: int, message: str, detail: Any = None,
                   headers: Mapping[str, str] | None = None) -> web.Response:
    response = web.json_response({"error": message, "detail": detail}, status=status)
    response.headers.update(headers or {})
    return response


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
        if self.security.guessing(request.headers, request.query, request.remote):
            raise ApiError(429, "too many wrong tokens from this address",
                           "tokens from it are refused unchecked for a while; wait a second",
                           {"Retry-After": "1"})
        if not self.security.token_ok(request.headers, request.query, request.remote):
            raise ApiError(401, "a valid bearer token is required",
                           "send 'Authorization: Bearer <token>'",
                           {"WWW-Authenticate": 'Bearer realm="arbiterd"'})

    def authorize(self, access: Access, request: web.Request) -> None:
        """:meth:`check` from inside a handler (the Host was checked on the way in)."""
        self.check(access, request, request.headers.get("Host"))


# -- request bodies ------------------------------------------------------------------------

async def read_body(request: web.Request, max_bytes: int, timeout_s: float) -> bytes:
    """The whole body (however many TCP segments it takes), decoded from its
    Content-Encoding, at most ``max_bytes``, within ``timeout_s``; or :class:`ApiError`."""
    if request.content_length is not None and request.content_length > max_bytes:
        raise ApiError(413, f"body too large: {request.content_length} bytes, "
                       f"limit {max_bytes}")
    chunks: list[bytes] = []
    size = 0
    try:
        async with asyncio.timeout(timeout_s):
            while chunk := await request.content.read(READ_CHUNK):
                size += len(chunk)
                if size > max_bytes:
                    raise ApiError(413, f"body too large: over {max_bytes} bytes")
                chunks.append(chunk)
    except TimeoutError:
        raise ApiError(408, f"body not received within {timeout_s:g} s",
                       f"got {size} bytes; [http] body_timeout_s sets the limit") from None
    except ConnectionError:  # the client went away mid-body: one line, no traceback
        raise ApiError(400, "body cut off", f"the client closed the connection after {size} "
                       "bytes") from None
    except web.RequestPayloadError as exc:
        raise ApiError(400, "body cannot be read", one_line(str(exc))) from None
    return b"".join(chunks)


async def read_json_body(request: web.Request, max_bytes: int, timeout_s: float) -> bytes:
    """The raw body of a request that says it is JSON (415 otherwise)."""
    if request.content_type != "application/json":
        raise ApiError(415, "content type must be application/json",
                       f"got {request.content_type or 'none'}")
    return await read_body(request, max_bytes, timeout_s)


async def read_json_object(request: web.Request, max_bytes: int,
                           timeout_s: float = 10.0) -> dict[str, Any]:
    """The request body as a JSON object, or :class:`ApiError` saying what is wrong with it."""
    return json_object(await read_json_body(request, max_bytes, timeout_s))


def json_object(raw: bytes) -> dict[str, Any]:
    body = parse_json(raw)
    if not isinstance(body, dict):
        raise ApiError(400, "body must be a JSON object", f"got {type(body).__name__}")
    return body


def parse_json(raw: bytes) -> Any:
    """Strict JSON: UTF-8 only, no NaN/Infinity, integers of at most 64 digits, nesting at
    most 32 deep; anything else is :class:`ApiError` 400 saying where."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ApiError(400, "body is not valid UTF-8", f"byte 0x{raw[exc.start]:02x} at "
                       f"offset {exc.start}: {exc.reason}") from None
    try:
        value = json.loads(text, parse_constant=_refuse_constant, parse_int=_bounded_int)
    except RecursionError:
        raise ApiError(400, "body is not valid JSON", f"nested more than {MAX_JSON_DEPTH} "
                       "deep") from None
    except ValueError as exc:
        raise ApiError(400, "body is not valid JSON", str(exc)) from None
    if _depth(value) > MAX_JSON_DEPTH:
        raise ApiError(400, "body is not valid JSON", f"nested more than {MAX_JSON_DEPTH} deep")
    return value


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a valid JSON number")


def _bounded_int(digits: str) -> int:
    if len(digits.lstrip("-")) > MAX_INT_DIGITS:
        raise ValueError(f"an integer of {len(digits.lstrip('-'))} digits; at most "
                         f"{MAX_INT_DIGITS} are accepted")
    return int(digits)


def _depth(value: Any) -> int:
    """Nesting depth of a parsed JSON value, without recursion."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict | list):
            deepest = max(deepest, depth)
            children = item.values() if isinstance(item, dict) else item
            stack.extend((child, depth + 1) for child in children
                         if isinstance(child, dict | list))
    return deepest


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

    def health(self) -> dict[str, Any]:
        running = self._runner is not None
        server = self._runner.server if self._runner else None
        return {"status": "ok" if running else "error", "port": self.bound_port,
                "connections": len(server.connections) if server else 0,
                "connections_refused": getattr(server, "refused", 0),
                "accept_errors": self._accept_errors.count if self._accept_errors else 0}


def create(ctx: DaemonContext) -> HttpServer | None:
    """The server every route is added to (built first, started last, stopped first)."""
    return ctx.http if ctx.settings(HttpSettings).enabled else None


def listens(config: Config) -> list[Listener]:
    http = config.get(HttpSettings)
    return [Listener("http", http.host, http.port)] if http.enabled else []


COMPONENT = ComponentSpec("http", create, HttpSettings, listens=listens)
