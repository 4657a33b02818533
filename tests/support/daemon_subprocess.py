# Test harness: the real `arbiterd run` as a subprocess on free ports, plus small HTTP helpers.
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def wait_for(predicate: Callable[[], Any], timeout: float = 10.0, what: str = "condition",
             interval: float = 0.02) -> Any:
    """Poll ``predicate`` until it returns something truthy; fail after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


def http(method: str, url: str, body: Any = None, *, token: str | None = None,
         raw: bytes | None = None, content_type: str = "application/json",
         timeout: float = 5.0) -> tuple[int, Any]:
    """One HTTP request; returns (status, parsed JSON or text)."""
    data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
    request = urllib.request.Request(url, data=data, method=method)
    if data is not None:
        request.add_header("Content-Type", content_type)
    if token:
        request.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(request, timeout=timeout) as response:
            return response.status, _decode(response.read())
    except urllib.error.HTTPError as exc:
        return exc.code, _decode(exc.read())


def _decode(payload: bytes) -> Any:
    try:
        return json.loads(payload)
    except ValueError:
        return payload.decode(errors="replace")


def read_wheel_log(path: Path) -> list[tuple[float, float, float]]:
    """The mock driver's ``log_file``: (monotonic time, left, right) per command."""
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        parts = line.split()
        if len(parts) == 3:
            rows.append((float(parts[0]), float(parts[1]), float(parts[2])))
    return rows


class DaemonProcess:
    """``arbiterd run --config <file>`` with HTTP on a free port and the mock driver logging."""

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

    def start(self, wait_ready: bool = True) -> DaemonProcess:
        self._log = self.log_path.open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "daemon.cli", "run", "--config", str(self.config_path),
             *self.args], cwd=REPO, env=self.env, stdout=self._log, stderr=subprocess.STDOUT,
            text=True)
        if wait_ready:
            wait_for(self._health_answers, 20.0, "the daemon's /api/health")
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

    def __enter__(self) -> DaemonProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)
        if hasattr(self, "_log"):
            self._log.close()
