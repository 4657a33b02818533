# HTTP connection layer under aiohttp: JSON parser errors, a connection cap, quiet accept errors.
from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import socket
import struct
import time
from collections.abc import Awaitable, Callable
from typing import Any

from aiohttp import web
from aiohttp.web_protocol import RequestHandler
from aiohttp.web_request import BaseRequest

from daemon.web import one_line

log = logging.getLogger("arbiterd.http")

ACCEPT_ERRNOS = {errno.EMFILE: "too many open files (EMFILE)",
                 errno.ENFILE: "the system file table is full (ENFILE)",
                 errno.ENOBUFS: "no buffer space (ENOBUFS)", errno.ENOMEM: "out of memory (ENOMEM)"}


class LogLimiter:
    """At most ``burst`` lines per ``window_s``; the next line after a window says how many
    were left out. Keeps a client that sends garbage from flooding the journal."""

    def __init__(self, logger: logging.Logger, what: str, burst: int = 5,
                 window_s: float = 10.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.logger = logger
        self.what = what
        self.burst = burst
        self.window_s = window_s
        self.clock = clock
        self._window_start = -float("inf")
        self._count = 0
        self.suppressed = 0

    def __call__(self, level: int, message: str, *args: Any, exc_info: Any = None) -> None:
        now = self.clock()
        if now - self._window_start >= self.window_s:
            if self.suppressed:
                self.logger.log(level, "%d more %s lines not logged in the last %.0f s",
                                self.suppressed, self.what, now - self._window_start)
            self._window_start, self._count, self.suppressed = now, 0, 0
        if self._count < self.burst:
            self._count += 1
            self.logger.log(level, message, *args, exc_info=exc_info)
        else:
            self.suppressed += 1


bad_request_log = LogLimiter(log, "bad-request")


#: on every answer of the API (and its errors): no content sniffing, nothing cached
API_HEADERS = {"X-Content-Type-Options": "nosniff", "Cache-Control": "no-store"}


def error_body(status: int, message: str, detail: Any = None) -> web.Response:
    return web.json_response({"error": message, "detail": detail}, status=status,
                             headers=API_HEADERS)


class JsonRequestHandler(RequestHandler):
    """aiohttp's protocol, answering its own parser errors (bad request line, bad or oversized
    headers, bad chunking) with the documented JSON error and one rate-limited log line instead
    of text/plain and a traceback. aiohttp has no public hook for these (aio-libs/aiohttp#3287)."""

    def handle_error(self, request: BaseRequest, status: int = 500,
                     exc: BaseException | None = None,
                     message: str | None = None) -> web.StreamResponse:
        if request.writer.output_size > 0:  # the answer has started: only closing is left
            raise ConnectionError("response already started; closing the connection")
        text = one_line(message or (str(exc) if exc else "")) or "bad request"
        if status >= 500:
            bad_request_log(logging.ERROR, "HTTP %d from %s: %s", status, request.remote,
                            text, exc_info=exc)
            response = error_body(status, "internal error", "see the daemon log")
        else:
            bad_request_log(logging.WARNING, "bad HTTP request from %s: %d %s", request.remote,
                            status, text)
            response = error_body(status, "malformed HTTP request", text)
        response.force_close()
        return response

    async def finish_response(self, request: BaseRequest, resp: web.StreamResponse,
                              start_time: float | None) -> tuple[web.StreamResponse, bool]:
        """aiohttp's, watched when the server has a send timeout: an answer (a big map as
        JSON) to a client that stops reading would otherwise wait on the socket for ever,
        holding its connection slot. When no byte of it leaves for ``send_timeout_s`` (as for
        a download), the connection is reset."""
        timeout = getattr(self._manager, "send_timeout_s", None)
        finishing = asyncio.ensure_future(super().finish_response(request, resp, start_time))
        if timeout is None:
            return await finishing
        queued = -1
        while True:
            done, _ = await asyncio.wait((finishing,), timeout=timeout)
            if done:
                return finishing.result()
            transport = self.transport
            now = transport.get_write_buffer_size() if transport is not None else 0
            if 0 <= queued <= now or transport is None:
                break
            queued = now
        finishing.cancel()
        bad_request_log(logging.WARNING, "HTTP answer to %s closed: it made no progress for %g "
                        "s (%d bytes still queued); [http] send_timeout_s sets the limit",
                        request.remote, timeout, queued)
        abort_with_reset(self.transport)
        self.force_close()
        return resp, True

    def log_exception(self, *args: Any, **kw: Any) -> None:
        """aiohttp's own "Unhandled exception" (e.g. a corrupt body it drains after the answer):
        one rate-limited line, no traceback."""
        exc = kw.get("exc_info")
        detail = one_line(str(exc)) if isinstance(exc, BaseException) else ""
        bad_request_log(logging.WARNING, "HTTP connection closed: %s%s", args[0] if args else
                        "error", f": {type(exc).__name__}: {detail}" if detail else "")

    #: let in beyond the cap while every connection was busy: serves only the routes that
    #: must always answer (the e-stop, health)
    priority_only = False

    @property
    def closing(self) -> bool:
        return self._force_close or self.transport is None

    @property
    def idle(self) -> bool:
        """Waiting for (the rest of) a request line and headers, nothing being answered."""
        return not self._request_in_progress and not self._messages and not self.closing


def abort_with_reset(transport: asyncio.Transport | None) -> None:
    """Close a connection at once with a reset, dropping what is still queued for it (a plain
    close would leave the kernel sending it to a client that reads nothing, for minutes)."""
    if transport is None:
        return
    sock = transport.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    transport.abort()


class CappedServer(web.Server):
    """The low-level server with :class:`JsonRequestHandler` and at most ``max_connections``
    open: a new connection beyond the cap closes the oldest idle one (or itself if every
    connection is busy), so idle sockets cannot use up the file descriptors. Used by both
    ports: ``label`` and ``setting`` name the server and its key in the log line."""

    max_connections = 256
    #: beyond the cap, while every connection is busy: connections for the priority routes
    reserved = 0
    #: an answer's time to be taken by its client, per 64 KiB (None: no deadline)
    send_timeout_s: float | None = None
    refused = 0
    label = "HTTP"
    setting = "[http] max_connections"

    def __call__(self) -> RequestHandler:
        return JsonRequestHandler(self, loop=self._loop, **self._kwargs)

    def connection_made(self, handler: RequestHandler, transport: asyncio.Transport) -> None:
        super().connection_made(handler, transport)
        if len(self._connections) <= self.max_connections:
            return
        live = [h for h in self._connections if not getattr(h, "closing", False)]
        if len(live) <= self.max_connections:
            return  # the rest are closing already (their sockets go on the next loop pass)
        victim = next((h for h in live if h is not handler and getattr(h, "idle", False)),
                      None)
        if victim is None and len(live) <= self.max_connections + self.reserved:
            handler.priority_only = True  # type: ignore[attr-defined]
            return
        victim = victim or handler
        self.refused += 1
        bad_request_log(logging.WARNING, "%s connection limit (%d) reached: closing %s "
                        "connection; %s sets it", self.label, self.max_connections,
                        "the oldest idle" if victim is not handler else "the new",
                        self.setting)
        # marked closing now (the next connection must not pick it again), closed on the next
        # pass: closing the new handler inside connection_made, before its task started,
        # made aiohttp log an AssertionError traceback per refused connection
        victim._force_close = True
        self._loop.call_soon(victim.force_close)


def json_http_errors(handler: Callable[[BaseRequest], Awaitable[web.StreamResponse]]
                     ) -> Callable[[BaseRequest], Awaitable[web.StreamResponse]]:
    """The application's handler, with the HTTP errors aiohttp raises before the middlewares
    run (e.g. 417 for an unknown ``Expect``) answered as the JSON error too."""

    async def handle(request: BaseRequest) -> web.StreamResponse:
        try:
            return await handler(request)
        except web.HTTPException as exc:
            if exc.status < 400:
                raise
            bad_request_log(logging.WARNING, "bad HTTP request from %s: %s %s -> %d %s",
                            request.remote, request.method, request.path[:100], exc.status,
                            exc.reason)
            response = error_body(exc.status, exc.reason, one_line(exc.text or ""))
            response.headers.update({k: v for k, v in exc.headers.items() if k == "Allow"})
            return response

    return handle


class CappedRunner(web.AppRunner):
    """An :class:`~aiohttp.web.AppRunner` whose server is a :class:`CappedServer`."""

    def __init__(self, app: web.Application, max_connections: int, *, reserved: int = 0,
                 label: str = "HTTP", setting: str = "[http] max_connections",
                 send_timeout_s: float | None = None, **kwargs: Any) -> None:
        super().__init__(app, **kwargs)
        self.max_connections = max_connections
        self.reserved = reserved
        self.send_timeout_s = send_timeout_s
        self.label, self.setting = label, setting

    async def _make_server(self) -> web.Server:
        server = await super()._make_server()
        server.__class__ = CappedServer  # same state, our handler class and the cap
        assert isinstance(server, CappedServer)
        server.max_connections = self.max_connections
        server.reserved = self.reserved
        server.send_timeout_s = self.send_timeout_s
        server.label, server.setting = self.label, self.setting
        server.request_handler = json_http_errors(server.request_handler)
        return server


class AcceptErrorFilter:
    """A loop exception handler: when ``accept()`` fails for lack of descriptors or memory
    (asyncio retries every second and would log a traceback each time), log one rate-limited
    line naming the cause and the fix; hand everything else to the previous handler."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        self.previous = loop.get_exception_handler()
        self.limiter = LogLimiter(log, "accept-error", burst=1, window_s=30.0)
        self.count = 0

    def install(self) -> None:
        self.loop.set_exception_handler(self)

    def uninstall(self) -> None:
        if self.loop.get_exception_handler() is self:
            self.loop.set_exception_handler(self.previous)

    def __call__(self, loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        exc = context.get("exception")
        if isinstance(exc, OSError) and _is_accept_failure(context):
            self.count += 1
            cause = ACCEPT_ERRNOS.get(exc.errno or 0, exc.strerror or str(exc))
            self.limiter(logging.ERROR, "cannot accept connections: %s; raise LimitNOFILE= in "
                         "the unit or lower [http] or [rosbridge] max_connections (retrying "
                         "each second)",
                         cause)
            return
        if self.previous is not None:
            self.previous(loop, context)
        else:
            loop.default_exception_handler(context)


def _is_accept_failure(context: dict[str, Any]) -> bool:
    message = str(context.get("message", ""))
    return message.startswith("socket.accept()") or "_accept_connection" in repr(
        context.get("handle"))
