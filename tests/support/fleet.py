# Fleet test helpers: an in-process Zenoh router with users, and sessions that talk to it.
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from daemon.components.fleet.zconfig import robot_config, router_config
from tests.support.net import free_port, http
from tests.support.paths import REPO
from tests.support.wait import wait_for

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


class FleetSubprocess:
    """``arbiterd fleet`` as a subprocess on free ports, with the users of :func:`zenoh_router`
    and a token for the fleet page."""

    TOKEN = "fleet-page-token-123"

    def __init__(self, tmp_path: Path) -> None:
        self.tmp_path = tmp_path
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.http_port = free_port()
        users = tmp_path / "fleet-users.txt"
        lines = [f"{OPERATOR}:{OPERATOR_PASSWORD}"] + [
            f"robot{i}:robot{i}-secret" for i in range(1, 11)]
        users.write_text("\n".join(lines) + "\n")
        self.config = tmp_path / "fleet.toml"
        self.config.write_text(f'[fleet]\noperator.users_file = "{users}"\n'
                               f'operator.operators = ["{OPERATOR}"]\n'
                               f'operator.http_host = "127.0.0.1"\noperator.stale_s = 2.0\n'
                               f'[security]\ntoken = "{self.TOKEN}"\n')
        self.proc: subprocess.Popen[str] | None = None
        self.log_path = tmp_path / "fleet.log"

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.http_port}"

    def start(self) -> FleetSubprocess:
        self._log = self.log_path.open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "daemon.cli", "fleet", "--listen", self.endpoint,
             "--http-port", str(self.http_port), "--config", str(self.config)],
            cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"}, stdout=self._log,
            stderr=subprocess.STDOUT, text=True)
        wait_for(self._answers, lambda: "the fleet page; its log:\n" + self.log()[-3000:],
                 within_s=30.0)
        return self

    def _answers(self) -> bool:
        if self.proc is not None and self.proc.poll() is not None:
            raise AssertionError(f"arbiterd fleet exited:\n{self.log()}")
        try:
            return http("GET", self.url + "/api/robots", timeout=1.0)[0] == 200
        except OSError:
            return False

    def log(self) -> str:
        return self.log_path.read_text()

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()

    def __enter__(self) -> FleetSubprocess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def robot_toml(endpoint: str, n: int) -> str:
    """[fleet] for simulated robot ``robot<n>`` of :class:`FleetSubprocess`."""
    return fleet_toml(endpoint, f"robot{n}", user=f"robot{n}", password=f"robot{n}-secret")
