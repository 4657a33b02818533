# This machine as a robot, in a private mount namespace: /etc, /opt, /usr/local and /var are
# overlays whose writes land in a scratch dir; systemctl (fake_systemctl.py), udevadm, sudo and
# sudoedit are stand-ins on PATH. Lets a test run install commands exactly as a user types them.
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from tests.support.deploy import fake_service_pid

FAKE_SYSTEMCTL = Path(__file__).with_name("fake_systemctl.py")
OVERLAID = ("/etc", "/opt", "/usr/local", "/var")


def available() -> str:
    """'' when a private mount namespace with overlays can be made here, else why not."""
    if os.geteuid() != 0:
        return "needs root (a private mount namespace with overlays)"
    if shutil.which("unshare") is None:
        return "needs unshare (util-linux)"
    return ""


class Machine:
    """Run shell scripts as root on this machine with its system directories overlaid."""

    def __init__(self, work: Path) -> None:
        self.work = work
        self.state = work / "systemd-state"  # the fake systemd's calls, service log and pid
        self.fakes = work / "fakes"
        for path in (self.state, self.fakes):
            path.mkdir(parents=True)
        self.state.chmod(0o755)  # the service user reaches the notify socket in it
        self._write_fakes()

    def upper(self, path: str) -> Path:
        """Where the overlay of a system directory keeps what was written below ``path``."""
        top = next(d for d in OVERLAID if path == d or path.startswith(d + "/"))
        return self.work / "upper" / top.strip("/").replace("/", "-") / path[len(top):].lstrip("/")

    def _write_fakes(self) -> None:
        scripts = {
            "systemctl": f'exec {sys.executable} {FAKE_SYSTEMCTL} "$@"',
            "udevadm": f'echo "udevadm $*" >>{self.state}/udevadm.log',
            "sudo": 'exec "$@"',  # we are root already; real sudo also finds /usr/local/bin
            "sudoedit": 'exec ${SUDO_EDITOR:?} "$@"',  # split into words, as sudoedit does
        }
        for name, body in scripts.items():
            path = self.fakes / name
            path.write_text(f"#!/bin/sh\n{body}\n")
            path.chmod(0o755)

    def _mounts(self) -> str:
        lines = []
        for top in OVERLAID:
            name = top.strip("/").replace("/", "-")
            upper, scratch = self.work / "upper" / name, self.work / "overlay-work" / name
            upper.mkdir(parents=True, exist_ok=True)
            scratch.mkdir(parents=True, exist_ok=True)
            lines.append(f"mount -t overlay overlay -o lowerdir={top},upperdir={upper},"
                         f"workdir={scratch} {top}")
        return "\n".join(lines)

    def run(self, script: str, env: dict[str, str], cwd: Path,
            timeout_s: float = 600) -> subprocess.CompletedProcess[str]:
        """``script`` (bash) inside the namespace, with the stand-ins first on PATH."""
        path = self.work / "machine.sh"
        path.write_text(f"set -eu\n{self._mounts()}\n"
                        f"export PATH={self.fakes}:/usr/local/sbin:/usr/local/bin:"
                        f"/usr/sbin:/usr/bin:/sbin:/bin\n"
                        f"export FAKE_SYSTEMD_ROOT=/ FAKE_SYSTEMD_STATE={self.state}\n"
                        f"{script}\n")
        return subprocess.run(["unshare", "--mount", "--propagation", "private", "bash",
                               str(path)], capture_output=True, text=True, env=env, cwd=cwd,
                              timeout=timeout_s, check=False, stdin=subprocess.DEVNULL)

    def service_pid(self) -> int | None:
        return fake_service_pid(self.state)
