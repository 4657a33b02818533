# JSON over HTTP for every component: errors, answers, strict bodies; the HTTP port Protocol.
from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable, Callable, Mapping
from typing import Any, BinaryIO, Protocol

from aiohttp import web

from daemon.messages.convert import to_json
from daemon.topics import Access

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]
#: a valid request the robot refuses in its present state (e-stop latched, driver fault)
REFUSED = 409
MAX_JSON_DEPTH = 32
MAX_INT_DIGITS = 64
#: a request body is read in pieces of this size
READ_CHUNK = 65536

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


class HttpPort(Protocol):
    """The HTTP server as a component's handlers use it (``ctx.http``)."""

    @property
    def max_body_bytes(self) -> int: ...

    async def read_json(self, request: web.Request) -> dict[str, Any]:
        """The body as a JSON object within the server's size and time limits."""
        ...

    async def read_json_body(self, request: web.Request) -> bytes:
        """The raw JSON body within the server's size and time limits."""
        ...

    def authorize(self, access: Access, request: web.Request) -> None:
        """Check from inside a handler that the caller has ``access`` (:class:`ApiError`)."""
        ...

    async def send_file(self, request: web.Request, file: BinaryIO, size: int,
                        headers: Mapping[str, str]) -> web.StreamResponse:
        """Stream an open file as the answer, cutting off a client that stops reading."""
        ...


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


def one_line(text: str, limit: int = 200) -> str:
    """aiohttp's multi-line parser messages as one line, without the caret marker line."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and set(ln.strip()) != {"^"}]
    return " ".join(lines)[:limit]
