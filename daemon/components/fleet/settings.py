# [fleet]: the robot's Zenoh connection to the fleet router, its id, credentials and rates.
from __future__ import annotations

import re
from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option

MODES = ("client", "peer")
ROBOT_ID = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
LOG_LEVELS = ("debug", "info", "warning", "error")


def _robot_id(value: object) -> str | None:
    if value == "" or ROBOT_ID.match(str(value)):
        return None
    return "letters, digits, _ and -, at most 64 ('' = the host name)"


def _endpoint(value: object) -> str | None:
    text = str(value)
    if text == "" or re.match(r"^(tcp|udp|tls|quic)/[^/\s]+:\d{1,5}$", text):
        return None
    return "a Zenoh endpoint such as 'tcp/192.168.1.10:7447'"


@dataclass(frozen=True)
class FleetSettings(SectionSettings, section="fleet"):
    """The [fleet] section, read once."""

    enabled: bool = option(False, "join a fleet over Zenoh (needs the fleet extra: "
                           "eclipse-zenoh; docs/fleet.md)")
    router: str = option("", "the fleet router's Zenoh endpoint, e.g. 'tcp/192.168.1.10:7447' "
                         "(what `arbiterd fleet --listen` opened); '' with mode = peer: find "
                         "peers on the LAN", check=_endpoint)
    mode: str = option("client", "client: through the router only (nothing listens on the "
                       "robot); peer: also LAN peers found by multicast", choices=MODES)
    robot_id: str = option("", "the robot's name in the fleet (its key space arbiterd/<id>/...); "
                           "'' = the host name", check=_robot_id)
    allow_commands: bool = option(False, "accept goals, missions, fetches and driving from the "
                                  "fleet operator (the e-stop is always accepted from an "
                                  "authenticated operator)")
    user: str = option("", "the robot's user name on the router (Zenoh user-password "
                       "authentication); '' = none: telemetry only, no command is accepted")
    password: str = option("", "the robot's password on the router ('' = none, or "
                           "password_file)")
    password_file: str = option("", "file holding the password (first line); '' = none")
    require_auth: bool = option(True, "allow_commands needs credentials (user and password); "
                                "false only on a closed network")
    console_url: str = option("", "link to this robot's console on the fleet page ('' = "
                              "http://<host name>:<[http] port>/)")
    pose_rate: float = option(2.0, "odometry and map pose published per second", above=0.0,
                              maxval=50.0)
    scan_rate: float = option(0.5, "scans published per second (0 = none)", minval=0.0,
                              maxval=20.0)
    battery_rate: float = option(0.5, "battery states published per second", above=0.0,
                                 maxval=20.0)
    map_period_s: float = option(5.0, "least time between two published maps (sent only when "
                                 "changed, zlib-compressed), s", minval=0.5, maxval=3600.0)
    refresh_s: float = option(5.0, "health and battery are sent again this often even "
                              "unchanged (a late operator sees them), s", minval=0.5,
                              maxval=3600.0)
    log_level: str = option("warning", "log lines at or above this level go to the fleet",
                            choices=LOG_LEVELS)
    queue: int = option(64, "log events waiting for the publisher thread; beyond it the oldest "
                        "is dropped", minval=4, maxval=10000)
    command_priority: int = option(10, "arbiter priority of fleet commands", minval=0,
                                   maxval=100)
    command_timeout: float = option(0.0, "deadman of fleet driving commands, s (0: [control] "
                                    "cmd_vel_timeout)", minval=0.0, maxval=10.0)
    retry_s: float = option(1.0, "while the router is unreachable, try again this often, s",
                            above=0.0, maxval=60.0)
    operator_listen: str = option("tcp/0.0.0.0:7447", "`arbiterd fleet`: the router's listen "
                                  "endpoint (--listen)", key="operator.listen", check=_endpoint)
    operator_http_host: str = option("0.0.0.0", "`arbiterd fleet`: the fleet page's listen "
                                     "address", key="operator.http_host")
    operator_http_port: int = option(8086, "`arbiterd fleet`: the fleet page's port "
                                     "(--http-port)", key="operator.http_port", minval=1,
                                     maxval=65535)
    operator_users_file: str = option("", "`arbiterd fleet`: Zenoh user-password dictionary "
                                      "(user:password per line; robots and operators); '' = "
                                      "no authentication: robots then accept no command",
                                      key="operator.users_file")
    operator_operators: list[str] = option([], "`arbiterd fleet`: the users of users_file who "
                                           "may command robots (the others are robots)",
                                           key="operator.operators")
    operator_stale_s: float = option(5.0, "`arbiterd fleet`: a robot unheard of this long is "
                                     "shown stale, s", key="operator.stale_s", above=0.0,
                                     maxval=3600.0)
