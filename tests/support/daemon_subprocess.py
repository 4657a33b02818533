# Test harness: the real `arbiterd run` as a subprocess on free ports, driven over HTTP (blocking).
from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tests.support.mock_wheel_log import read_wheel_log
from tests.support.net import free_port, http
from tests.support.paths import REPO
from tests.support.wait import wait_for


class DaemonSubprocess:
    """``arbiterd run --config <file>`` as a subprocess, with HTTP on a free port and the mock
    driver logging (blocking calls; for async tests see async_daemon_subprocess.py)."""

    def __init__(self, tmp_path: Path, extra_toml: str = "", *,
                 env: dict[str, str] | None = None, args: tuple[str, ...] = (),
                 use_mock_log: bool = True) -> None:
        self.tmp_path = tmp_path
        self.http_port = free_port()
        self.ws_port = free_port()
        self.wheel_log = tmp_path / "wheels.log"
        self.config_path = tmp_path / "arbiterd.toml"
        base = f"[http]\nhost = \"127.0.0.1\"\nport = {self.http_port}\n"
        base += f"[rosbridge]\nhost = \"127.0.0.1\"\nport = {self.ws_port}\n"
        if use_mock_log:
            base += f"[driver.mock]\nlog_file = \"{self.wheel_log}\"\n"
        self.config_path.write_text(base + extra_toml)
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.args = args
        self.proc: subprocess.Popen[str] | None = None
        self.log_path = tmp_path / "daemon.log"

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.http_port}"

    def command(self) -> list[str]:
        """The command line the subprocess runs."""
        return [sys.executable, "-m", "daemon.cli", "run", "--config", str(self.config_path),
                *self.args]

    def start(self, wait_ready: bool = True) -> DaemonSubprocess:
        self._log = self.log_path.open("w")
        self.proc = subprocess.Popen(self.command(), cwd=REPO, env=self.env, stdout=self._log,
                                     stderr=subprocess.STDOUT, text=True)
        if wait_ready:
            wait_for(self._health_answers, lambda: "the daemon's /api/health; its log ends:\n"
                     + self.log()[-4000:], within_s=60.0)
        return self

    def _health_answers(self) -> bool:
        if self.proc is not None and self.proc.poll() is not None:
            raise AssertionError(f"daemon exited with {self.proc.returncode}:\n{self.log()}")
        try:
            status, _ = http("GET", self.base_url + "/api/health", timeout=1.0)
        except OSError:
            return False
        return status in (200, 503)

    def get(self, path: str, **kw: Any) -> tuple[int, Any]:
        return http("GET", self.base_url + path, **kw)

    def post(self, path: str, body: Any = None, **kw: Any) -> tuple[int, Any]:
        return http("POST", self.base_url + path, body, **kw)

    def wheels(self) -> list[tuple[float, float, float]]:
        return read_wheel_log(self.wheel_log)

    def log(self) -> str:
        return self.log_path.read_text() if self.log_path.exists() else ""

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 15.0) -> int:
        assert self.proc is not None
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        code = self.proc.wait(timeout)
        self._log.close()
        return code

    def __enter__(self) -> DaemonSubprocess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)
        if hasattr(self, "_log"):
            self._log.close()


#: The ``daemon_subprocess`` fixture: starts a DaemonSubprocess (``extra_toml``, keyword
#: arguments of DaemonSubprocess, ``wait_ready``), killed at the end of the test.
StartDaemonSubprocess = Callable[..., DaemonSubprocess]
