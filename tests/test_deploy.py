# deploy-pi.sh against a real sshd and a fake Pi root whose daemon is a real `arbiterd run --sim`.
from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import urllib.error
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.support.deploy import DEPLOY_SH, fake_service_pid
from tests.support.deploy.machine import FAKE_SYSTEMCTL
from tests.support.deploy.sshd import SshServer, start_sshd
from tests.support.deploy.wheels import Wheels, wheels
from tests.support.net import free_port
from tests.support.wait import wait_for

HEALTH_TIMEOUT_S = 60
KEEP = 3


@dataclass
class FakePi:
    root: Path
    http_port: int
    ssh: SshServer
    built: Wheels

    def deploy(self, *args: str) -> subprocess.CompletedProcess[str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith("ARBITERD_")}
        env["ARBITERD_SSH_OPTS"] = self.ssh.client_options
        cmd = ["bash", str(DEPLOY_SH), f"{self.ssh.user}@127.0.0.1", "--port", str(self.ssh.port),
               "--identity", str(self.ssh.identity), "--remote-root", str(self.root),
               "--wheelhouse", str(self.built.wheelhouse), "--keep", str(KEEP),
               "--health-timeout", str(HEALTH_TIMEOUT_S), *args]
        return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600,
                              check=False, stdin=subprocess.DEVNULL)

    def current(self) -> str:
        return os.readlink(self.root / "opt/arbiterd/current").removeprefix("releases/")

    def history(self) -> list[str]:
        return (self.root / "opt/arbiterd/history").read_text().split()

    def daemon_pid(self) -> int | None:
        return fake_service_pid(self.root / "run/fake-systemd")

    def serving_release(self) -> str:
        """The release whose interpreter runs the daemon process (its venv's script shebang)."""
        pid = self.daemon_pid()
        assert pid is not None, "no daemon running"
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        marker = str(self.root / "opt/arbiterd/releases") + "/"
        python = argv[0].decode()
        assert python.startswith(marker), argv
        return python[len(marker):].split("/", 1)[0]

    def health(self) -> dict[str, Any]:
        url = f"http://127.0.0.1:{self.http_port}/api/health"
        with urllib.request.urlopen(url, timeout=5) as response:
            body: dict[str, Any] = json.load(response)
        return body

    def daemon_log(self) -> str:
        return (self.root / "var/log/arbiterd.log").read_text(errors="replace")

    def systemctl_calls(self) -> list[str]:
        return (self.root / "var/log/systemctl.log").read_text().splitlines()


def write_config(root: Path, http_port: int) -> None:
    etc = root / "etc/arbiterd"
    etc.mkdir(parents=True)
    (etc / "arbiterd.toml").write_text(
        f'[driver]\ntype = "mock"\n\n[http]\nhost = "127.0.0.1"\nport = {http_port}\n\n'
        f'[rosbridge]\nhost = "127.0.0.1"\nport = {free_port()}\n')


def stop_daemon(pi: FakePi) -> None:
    pid = pi.daemon_pid()
    if pid is None:
        return
    try:
        os.kill(pid, signal.SIGTERM)
    except ProcessLookupError:
        return
    try:
        wait_for(lambda: exited(pid), f"the daemon (pid {pid}) to exit on SIGTERM", within_s=10,
                 interval_s=0.05)
    except AssertionError:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


def exited(pid: int) -> bool:
    """The process is gone, or a zombie (it exited; its parent has not reaped it yet)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


#: each test may pay for the module's first deploy: a release venv installed offline (numpy,
#: scipy, aiohttp...), a minute or two on a busy 2-core machine
pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def pi(tmp_path_factory: pytest.TempPathFactory) -> Iterator[FakePi]:
    """A fake Pi reachable over ssh, with a first release deployed and healthy."""
    work = tmp_path_factory.mktemp("deploy")
    built = wheels(tmp_path_factory)
    root = work / "pi-root"
    http_port = free_port()
    write_config(root, http_port)
    ssh = start_sshd(work / "ssh", {"ARBITERD_SYSTEMCTL": str(FAKE_SYSTEMCTL),
                                     "FAKE_SYSTEMD_ROOT": str(root)})
    fake = FakePi(root=root, http_port=http_port, ssh=ssh, built=built)
    try:
        first = fake.deploy("--wheel", str(built.wheel))
        assert first.returncode == 0, first.stdout + first.stderr
        yield fake
    finally:
        stop_daemon(fake)
        ssh.stop()


def test_good_deploy_switches_releases(pi: FakePi) -> None:
    before = pi.current()
    result = pi.deploy()  # builds the wheel from this checkout
    assert result.returncode == 0, result.stdout + result.stderr
    after = pi.current()
    assert after != before
    assert f"deployed {after}: healthy" in result.stdout
    assert pi.history()[-2:] == [before, after]
    assert pi.serving_release() == after
    health = pi.health()
    assert health["status"] == "ok" and health["mode"] == "sim"
    assert "restart arbiterd.service" in pi.systemctl_calls()
    assert "ExecStopPost exit 0" in pi.systemctl_calls()  # safe-stop after the old one stopped
    # in sim mode (ARBITERD_ARGS=--sim reaches safe-stop too) it opens no serial port
    assert "simulated robot (--sim): no hardware to zero" in pi.daemon_log()
    assert (pi.root / "opt/arbiterd/releases" / after / "venv/bin/arbiterd").exists()


def test_unhealthy_deploy_rolls_back_and_the_previous_release_serves(pi: FakePi) -> None:
    before = pi.current()
    result = pi.deploy("--wheel", str(pi.built.broken_wheel))
    assert result.returncode == 1, result.stdout + result.stderr
    assert "did not become healthy" in result.stdout
    assert f"failed its health check; rolled back to {before}, which is healthy" in result.stderr
    assert "deliberately broken release" in pi.daemon_log()
    assert pi.current() == before
    assert pi.history()[-1] == before
    assert pi.serving_release() == before
    assert pi.health()["status"] == "ok"


def test_rollback_on_demand(pi: FakePi) -> None:
    if len(set(pi.history())) < 2:
        deployed = pi.deploy("--wheel", str(pi.built.wheel))
        assert deployed.returncode == 0, deployed.stdout + deployed.stderr
    current = pi.current()
    previous = [name for name in pi.history() if name != current][-1]
    result = pi.deploy("--rollback")
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"rolled back from {current} to {previous}" in result.stdout
    assert pi.current() == previous
    assert pi.serving_release() == previous
    assert pi.health()["status"] == "ok"


def test_releases_outside_the_last_kept_are_pruned(pi: FakePi) -> None:
    releases_dir = pi.root / "opt/arbiterd/releases"
    stale = releases_dir / "0.0.1-stale"  # an old release no longer in the history
    stale.mkdir()
    deployed = pi.deploy("--wheel", str(pi.built.wheel))
    assert deployed.returncode == 0, deployed.stdout + deployed.stderr
    kept = set(list(dict.fromkeys(reversed(pi.history())))[:KEEP])  # newest distinct KEEP
    assert {p.name for p in releases_dir.iterdir()} == kept
    assert pi.current() in kept and not stale.exists()


def test_status_over_ssh_shows_state_health_and_latency(pi: FakePi) -> None:
    installer = pi.root / "opt/arbiterd/current/install.sh"
    remote = f"{installer} status --root {pi.root}"
    cmd = ["ssh", "-p", str(pi.ssh.port), "-i", str(pi.ssh.identity), "-o", "BatchMode=yes",
           *pi.ssh.client_options.split(), f"{pi.ssh.user}@127.0.0.1", remote]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Active: active" in result.stdout
    assert ": ok (" in result.stdout and "sim mode" in result.stdout
    assert "receipt->exec " in result.stdout and "tick lateness " in result.stdout


def test_unreachable_robot_is_reported(tmp_path: Path) -> None:
    result = subprocess.run(
        ["bash", str(DEPLOY_SH), "nobody@127.0.0.1", "--port", str(free_port()), "--rollback"],
        capture_output=True, text=True, timeout=60, check=False, stdin=subprocess.DEVNULL,
        env={**os.environ, "ARBITERD_SSH_OPTS": "-F /dev/null -o StrictHostKeyChecking=no"})
    assert result.returncode == 1
    assert "cannot run commands on nobody@127.0.0.1 over ssh" in result.stderr


def test_usage_errors() -> None:
    for args, message in [([], "which robot?"), (["pi", "--keep", "1"], "--keep 1: need >= 2"),
                          (["pi", "--wheel", "/nonexistent.whl"], "no such file")]:
        result = subprocess.run(["bash", str(DEPLOY_SH), *args], capture_output=True, text=True,
                                timeout=30, check=False)
        assert result.returncode == 2 and message in result.stderr, result.stderr
