# [http]: the HTTP server's address, limits and the console switch.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option


@dataclass(frozen=True)
class HttpSettings(SectionSettings, section="http"):
    """The [http] section, read once (keys with dots as underscores)."""

    enabled: bool = option(True, "serve the HTTP API")
    host: str = option("0.0.0.0", "HTTP listen address")
    port: int = option(8085, "HTTP listen port", minval=1, maxval=65535)
    max_body_bytes: int = option(65536, "largest accepted request body (after Content-Encoding), "
                                 "bytes; larger gets 413", minval=64, maxval=16 * 1024 * 1024)
    body_timeout_s: float = option(10.0, "a request body must arrive within this long, s; slower "
                                   "gets 408", above=0.0, maxval=300.0)
    idle_timeout_s: float = option(15.0, "close a connection that sends no complete request line "
                                   "and headers for this long after it opened or after the last "
                                   "answer (keep-alive and header-read timeout), s", above=0.0,
                                   maxval=3600.0)
    max_connections: int = option(256, "most open HTTP connections; one more closes the oldest "
                                  "idle one (keep it well under LimitNOFILE)", minval=4,
                                  maxval=65536)
    reserved_connections: int = option(8, "connections let in beyond max_connections while every "
                                       "open one is busy (stalled downloads): they serve only "
                                       "POST /api/estop and GET /api/health", minval=0, maxval=1024)
    send_timeout_s: float = option(10.0, "close a connection whose answer makes no progress for "
                                   "this long (a download whose client stopped reading: one 64 "
                                   "KiB piece must go out within it), s", above=0.0, maxval=3600.0)
    console: bool = option(True, "serve the web console at / (its files are open; what moves the "
                           "robot still needs the token)")
