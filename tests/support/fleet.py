# Fleet test helpers: an in-process Zenoh router with users, and sessions that talk to it.
from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.components.fleet.zconfig import robot_config, router_config
from tests.support.net import free_port

OPERATOR, OPERATOR_PASSWORD = "teacher", "operator-secret"
ROBOT, ROBOT_PASSWORD = "robot1", "robot1-secret"


@dataclass
class Router:
    endpoint: str
    session: Any
    users_file: Path | None


def open_session(config: dict[str, Any]) -> Any:
    import zenoh

    return zenoh.open(zenoh.Config.from_json5(json.dumps(config)))


@contextmanager
def zenoh_router(tmp_path: Path, users: bool = True) -> Iterator[Router]:
    """A router on a free local port; with ``users``: the operator and one robot user, the
    robot forbidden to command."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    users_file = None
    if users:
        users_file = tmp_path / "fleet-users.txt"
        users_file.write_text(f"{OPERATOR}:{OPERATOR_PASSWORD}\n{ROBOT}:{ROBOT_PASSWORD}\n")
    session = open_session(router_config(endpoint, users_file, [OPERATOR]))
    try:
        yield Router(endpoint, session, users_file)
    finally:
        session.close()


def client(endpoint: str, user: str = "", password: str = "") -> Any:
    return open_session(robot_config(endpoint, "client", user, password))


def fleet_toml(endpoint: str, robot_id: str = "r1", *, allow_commands: bool = False,
               user: str = ROBOT, password: str = ROBOT_PASSWORD, extra: str = "") -> str:
    return (f'[fleet]\nenabled = true\nrouter = "{endpoint}"\nrobot_id = "{robot_id}"\n'
            f'allow_commands = {str(allow_commands).lower()}\nuser = "{user}"\n'
            f'password = "{password}"\n' + extra)
