# Who may reach and who may drive: the Host allow-list, the browser Origin check, the token.
from __future__ import annotations

import hmac
import ipaddress
import re
import socket
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Literal
from urllib.parse import urlsplit

#: what a request's token is: none needed or the right one, none offered, a wrong one, or a
#: wrong one from an address over its budget of wrong ones
TokenCheck = Literal["ok", "missing", "wrong", "guessing"]

LOCAL_NAMES = frozenset({"localhost", "localhost.localdomain", "ip6-localhost"})

#: an absolute file system path inside a text, of two segments or more (/dev/ttyUSB0,
#: /var/lib/arbiterd/recordings); not a one-segment topic name (/odom), nor a URL's path
_PATH = re.compile(r"(?<![\w/.:~-])/(?:[\w.@+~-]+/)+[\w.@+~-]*")
HIDDEN_PATH = "<path>"


def hide_paths(value: Any) -> Any:
    """``value`` (JSON-like) with every absolute path in its strings replaced by
    :data:`HIDDEN_PATH`: what a read-only client is shown (docs/security.md)."""
    if isinstance(value, str):
        return _PATH.sub(HIDDEN_PATH, value) if "/" in value else value
    if isinstance(value, dict):
        return {key: hide_paths(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [hide_paths(item) for item in value]
    return value


def machine_names() -> set[str]:
    """This machine's own names (short, fully qualified, and mDNS ``.local``), lower case."""
    names = {socket.gethostname(), socket.getfqdn()}
    short = {n.split(".", 1)[0] for n in names if n}
    return {n.lower() for n in names | short | {f"{s}.local" for s in short} if n}


def host_name(host_header: str) -> str | None:
    """The name part of a ``Host`` header (``name``, ``name:port``, ``[v6]:port``), lower
    case without a trailing dot; ``None`` when it is not a well-formed host."""
    try:
        parts = urlsplit(f"//{host_header}")
        name, _ = parts.hostname, parts.port  # .port raises on a malformed port
    except ValueError:
        return None
    if not name or parts.username is not None or parts.path or parts.query:
        return None
    return name.rstrip(".").lower()


def is_ip_literal(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


class Guesses:
    """Wrong tokens per peer address: ``burst`` at once, then ``rate`` a second. A peer over
    its budget has every wrong token it offers refused with 429 until the budget refills
    (the right one still passes: :meth:`Security.check_token`). At most ``max_peers`` are remembered
    (the longest unheard of is forgotten first)."""

    def __init__(self, rate: float = 1.0, burst: float = 10.0, max_peers: int = 4096,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.rate, self.burst, self.max_peers, self.clock = rate, burst, max_peers, clock
        self.refused = 0
        self._peers: OrderedDict[str, tuple[float, float]] = OrderedDict()  # level, when

    def _level(self, peer: str) -> float:
        level, since = self._peers.get(peer, (self.burst, self.clock()))
        return min(self.burst, level + (self.clock() - since) * self.rate)

    def allowed(self, peer: str) -> bool:
        if self._level(peer) >= 1.0:
            return True
        self.refused += 1
        return False

    def exhausted(self, peer: str) -> bool:
        return self._level(peer) < 1.0

    def failed(self, peer: str) -> None:
        self._peers[peer] = (self._level(peer) - 1.0, self.clock())
        self._peers.move_to_end(peer)
        while len(self._peers) > self.max_peers:
            self._peers.popitem(last=False)


class Security:
    """``[security]``: which Host names the daemon answers to, which browser Origins may open
    the WebSocket, and the token that everything moving the robot needs."""

    def __init__(self, token: str, allowed_origins: Iterable[str] = (),
                 read_requires_token: bool = False, allowed_hosts: Iterable[str] = (),
                 own_names: Iterable[str] | None = None) -> None:
        self.token = token
        self.allowed_origins = {o.rstrip("/").lower() for o in allowed_origins}
        self.read_requires_token = read_requires_token
        own = machine_names() if own_names is None else set(own_names)
        self.allowed_hosts = LOCAL_NAMES | {h.rstrip(".").lower() for h in allowed_hosts} | own
        #: wrong tokens per peer address, rate-limited
        self.guesses = Guesses()

    @property
    def token_required(self) -> bool:
        return bool(self.token)

    # -- who may reach it ----------------------------------------------------------------

    def host_ok(self, host_header: str | None) -> bool:
        """DNS rebinding guard: a browser tricked into calling the robot sends the attacker's
        name as ``Host``. IP literals, localhost, this machine's names and ``allowed_hosts``
        pass; a request without a ``Host`` header (not a browser) passes too."""
        if host_header is None:
            return True
        name = host_name(host_header)
        return name is not None and (is_ip_literal(name) or name in self.allowed_hosts)

    def origin_ok(self, origin: str | None, host_header: str | None) -> bool:
        """Non-browser clients send no Origin; a browser's Origin must be this host (same
        name as an allowed Host), localhost, or listed in ``allowed_origins``."""
        if not origin:
            return True
        if origin.rstrip("/").lower() in self.allowed_origins:
            return True
        parts = urlsplit(origin)
        if parts.scheme not in ("http", "https") or parts.username is not None:
            return False
        origin_host = host_name(parts.netloc)
        if origin_host is None:
            return False
        if origin_host in LOCAL_NAMES or origin_host in ("127.0.0.1", "::1"):
            return True
        request_host = host_name(host_header) if host_header else None
        return origin_host == request_host and self.host_ok(host_header)

    # -- who may drive -------------------------------------------------------------------

    def sees_paths(self, headers: Mapping[str, str], query: Mapping[str, str],
                   peer: str | None = None) -> bool:
        """Whether a request is shown this machine's file system paths (device nodes, the
        recordings directory): always without a token configured, else with the token."""
        return not self.token_required or self.token_ok(headers, query, peer)

    @staticmethod
    def offered(headers: Mapping[str, str], query: Mapping[str, str]) -> str:
        """The token a request offers: ``Authorization: Bearer T`` or ``?token=T`` (for
        browsers that cannot set headers); "" for none."""
        auth = headers.get("Authorization", "")
        return auth[7:].strip() if auth[:7].lower() == "bearer " else query.get("token", "")

    def token_ok(self, headers: Mapping[str, str], query: Mapping[str, str],
                 peer: str | None = None) -> bool:
        """The request shows the token (:meth:`check_token` says ``ok``)."""
        return self.check_token(headers, query, peer) == "ok"

    def check_token(self, headers: Mapping[str, str], query: Mapping[str, str],
                    peer: str | None = None) -> TokenCheck:
        """``ok``, ``missing`` or ``wrong``; ``guessing`` for a wrong one from an address over
        its budget of wrong ones. The right token is compared first, in constant time, and is
        never limited: a flood of wrong tokens from the owner's address (one NAT, one proxy)
        does not lock the owner out. Only failures count against the budget."""
        if not self.token:
            return "ok"
        offered = self.offered(headers, query)
        if not offered:
            return "missing"
        if hmac.compare_digest(offered.encode(), self.token.encode()):
            return "ok"
        if peer is None:
            return "wrong"
        if not self.guesses.allowed(peer):
            return "guessing"
        self.guesses.failed(peer)
        return "wrong"

    def guessing(self, headers: Mapping[str, str], query: Mapping[str, str],
                 peer: str | None) -> bool:
        """The request offers a wrong token from an address over its budget of wrong ones
        (the right token is never "guessing")."""
        return bool(self.token and peer is not None and self.offered(headers, query)
                    and self.guesses.exhausted(peer)
                    and self.check_token(headers, query, None) != "ok")
