# Who may do what over rosbridge: one table of ops (and the topic or service they name) -> access.
from __future__ import annotations

from dataclasses import dataclass

from daemon.components.rosbridge import rosapi
from daemon.components.rosbridge.codec import ProtocolError
from daemon.topics import Access

ANY = "*"  # every topic or service the table does not name

# The same words as the HTTP routes: "open" = any connected client; "stop" = the same over
# rosbridge (Host and Origin were checked at the upgrade; only the e-stop's latch declares it);
# "read" = a client that may read telemetry ([security] read_requires_token); "drive" = a
# client with the token, when one is configured. (op, canonical topic or service name) ->
# access; (op, ANY) is the rule for every other name. Ops without a topic or service are
# looked up as (op, ANY).
TABLE: dict[tuple[str, str], Access] = {
    # with a token configured, a tokenless client is read-only: it may not publish on any
    # topic (others use them), advertise topics or services, take a service over, answer
    # calls, or call client-provided services (they may act on the robot)
    ("advertise", ANY): "drive",
    ("publish", ANY): "drive",
    ("unadvertise", ANY): "open",
    ("subscribe", ANY): "read",
    ("unsubscribe", ANY): "open",
    **{("call_service", name): "read" for name in rosapi.SERVICES},
    ("call_service", ANY): "drive",
    ("advertise_service", ANY): "drive",
    ("unadvertise_service", ANY): "open",
    ("service_response", ANY): "drive",
    ("set_level", ANY): "open",
    ("fragment", ANY): "open",  # the joined request is checked on its own
}

TOKEN_HINT = "Authorization: Bearer <token> or ?token=<token>"


@dataclass(frozen=True)
class Authority:
    """What one connection proved when it connected. ``proved`` = it showed the configured
    token (never true without one): such clients get the reserved slots and no idle limit."""

    may_read: bool
    may_drive: bool
    proved: bool = False

    def allows(self, access: Access) -> bool:
        if access == "drive":
            return self.may_drive
        if access == "read":
            return self.may_read
        return True  # open, and stop: every connection passed Host and Origin at the upgrade


def required(op: str, target: str = ANY) -> Access:
    """The access ``op`` on ``target`` needs (KeyError for an op the table does not know)."""
    return TABLE.get((op, target)) or TABLE[(op, ANY)]


def check(op: str, target: str, authority: Authority, declared: Access | None = None) -> None:
    """The one access check: a ProtocolError when ``authority`` is not enough. ``declared``:
    what the robot's own incoming topic ``target`` declares for advertising and publishing."""
    access = declared or required(op, target or ANY)
    if authority.allows(access):
        return
    what = f"{op} {target}" if target and target != ANY else op
    limit = "read-only" if access == "drive" else "not allowed to read telemetry"
    raise ProtocolError(f"{what}: needs a valid token ({TOKEN_HINT}); without it this client "
                        f"is {limit}")
