# Who may drive: bearer-token checks and the browser Origin allow-list.
from __future__ import annotations

import hmac
from collections.abc import Mapping
from urllib.parse import urlsplit

from aiohttp import web

from daemon.http_api import ApiError

LOCAL_HOSTS = {"localhost", "127.0.0.1", "::1", "[::1]"}


class Security:
    """Token and Origin policy from ``[security]``."""

    def __init__(self, token: str, allowed_origins: list[str],
                 read_requires_token: bool = False) -> None:
        self.token = token
        self.allowed_origins = {o.rstrip("/").lower() for o in allowed_origins}
        self.read_requires_token = read_requires_token

    @property
    def token_required(self) -> bool:
        return bool(self.token)

    def token_ok(self, headers: Mapping[str, str], query: Mapping[str, str]) -> bool:
        """``Authorization: Bearer T`` or ``?token=T`` (for browsers that cannot set headers)."""
        if not self.token:
            return True
        auth = headers.get("Authorization", "")
        offered = auth[7:].strip() if auth[:7].lower() == "bearer " else query.get("token", "")
        return hmac.compare_digest(offered.encode(), self.token.encode())

    def require_token(self, request: web.Request) -> None:
        """For anything that moves the robot or releases an e-stop."""
        if not self.token_ok(request.headers, request.query):
            raise ApiError(401, "a valid bearer token is required",
                           "send 'Authorization: Bearer <token>'")

    def require_read(self, request: web.Request) -> None:
        if self.read_requires_token:
            self.require_token(request)

    def origin_ok(self, origin: str | None, host_header: str | None) -> bool:
        """Non-browser clients send no Origin; browsers must come from an allowed one."""
        if not origin:
            return True
        parts = urlsplit(origin)
        origin_host = (parts.hostname or "").lower()
        if origin_host in LOCAL_HOSTS or origin.rstrip("/").lower() in self.allowed_origins:
            return True
        request_host = (urlsplit(f"//{host_header}").hostname or "").lower() if host_header else ""
        return bool(request_host) and origin_host == request_host
