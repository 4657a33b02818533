#!/usr/bin/env python3
# A recording systemctl for a fake Pi root: runs arbiterd.service's ExecStart inside the root.
#
# Environment: FAKE_SYSTEMD_ROOT (the fake Pi's root; "/" for a whole machine in a private mount
# namespace) and FAKE_SYSTEMD_STATE (where calls, the service's output and state go; default
# <root>/var/log and <root>/run/fake-systemd). Absolute paths in the unit's command lines are
# taken inside the root, and $VARS come from its EnvironmentFile, as systemd would expand them.
# Like systemd for a Type=notify unit, `start` waits for READY=1 on NOTIFY_SOCKET (or the
# process's exit: then it fails); User=/Group= are honoured when that user exists, and
# StateDirectory= is created and passed as $STATE_DIRECTORY. A file
# <state>/fail-<verb> makes the next call of that verb fail once (and is removed).
from __future__ import annotations

import json
import os
import pwd
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(os.environ["FAKE_SYSTEMD_ROOT"])
UNIT = ROOT / "etc/systemd/system/arbiterd.service"
STATE_ENV = os.environ.get("FAKE_SYSTEMD_STATE", "")
RUN = Path(STATE_ENV) if STATE_ENV else ROOT / "run/fake-systemd"
LOGS = Path(STATE_ENV) if STATE_ENV else ROOT / "var/log"
STATE = RUN / "arbiterd.json"
LOG = LOGS / "arbiterd.log"
CALLS = LOGS / "systemctl.log"
STOP_TIMEOUT_S = 10.0
OURS = {"arbiterd.service", "arbiterd", "robot.target"}  # robot.target Wants=arbiterd


def unit_lines(key: str) -> list[str]:
    prefix = key + "="
    return [ln[len(prefix):] for ln in UNIT.read_text().splitlines() if ln.startswith(prefix)]


def environment() -> dict[str, str]:
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "PYTHONUNBUFFERED": "1"}
    for spec in unit_lines("EnvironmentFile"):
        path = ROOT / spec.lstrip("-").lstrip("/")
        if path.exists():
            for line in path.read_text().splitlines():
                if line.strip() and not line.startswith("#") and "=" in line:
                    key, _, value = line.partition("=")
                    env[key.strip()] = value.strip()
    for name in unit_lines("StateDirectory"):
        env["STATE_DIRECTORY"] = str(state_directory(name))
    return env


def state_directory(name: str) -> Path:
    """StateDirectory=: /var/lib/<name> in the root, created and owned by User= as systemd
    does before ExecStart."""
    path = ROOT / "var/lib" / name
    path.mkdir(parents=True, exist_ok=True)
    users = unit_lines("User")
    if users and os.geteuid() == 0:
        try:
            entry = pwd.getpwnam(users[0])
        except KeyError:  # a staging root: the service user exists only on the robot
            return path
        os.chown(path, entry.pw_uid, entry.pw_gid)
    return path


def command(key: str, env: dict[str, str]) -> list[str]:
    """The unit's command line: -/@ prefixes dropped, $VAR split into words, paths in ROOT,
    run as User= through setpriv when that user exists here."""
    words: list[str] = []
    for word in shlex.split(unit_lines(key)[0]):
        if word.startswith("$"):
            words += env.get(word.strip("${}"), "").split()
        else:
            words.append(word)
    words[0] = words[0].lstrip("-@:+!")
    argv = [str(ROOT / w.lstrip("/")) if w.startswith("/") else w for w in words]
    return as_unit_user() + argv


def as_unit_user() -> list[str]:
    users = unit_lines("User")
    if not users or os.geteuid() != 0:
        return []
    try:
        pwd.getpwnam(users[0])
    except KeyError:  # a staging root: the service user exists only on the robot
        return []
    group = (unit_lines("Group") or users)[0]
    return ["setpriv", f"--reuid={users[0]}", f"--regid={group}", "--init-groups", "--"]


def read_state() -> dict[str, object]:
    return json.loads(STATE.read_text()) if STATE.exists() else {}


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (exited, not yet reaped by its parent) is not running
    stat = Path(f"/proc/{pid}/stat")
    return stat.exists() and stat.read_text().rsplit(")", 1)[1].split()[0] != "Z"


def running_pid() -> int | None:
    pid = read_state().get("pid")
    return pid if isinstance(pid, int) and alive(pid) else None


def start_timeout_s() -> float:
    values = unit_lines("TimeoutStartSec")
    return float(values[0]) if values else 90.0


def start() -> int:
    if running_pid() is not None:
        return 0
    env = environment()
    argv = command("ExecStart", env)
    LOG.parent.mkdir(parents=True, exist_ok=True)
    RUN.mkdir(parents=True, exist_ok=True)
    # like /run/systemd/notify: reachable by the service user, whatever the state dir allows
    notify_dir = Path(tempfile.mkdtemp(prefix="fake-systemd-"))
    notify_dir.chmod(0o755)
    notify_path = notify_dir / "notify"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as notify:
        notify.bind(str(notify_path))
        notify_path.chmod(0o777)
        env["NOTIFY_SOCKET"] = str(notify_path)
        with LOG.open("ab") as log:
            proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
                                    env=env, cwd=ROOT, start_new_session=True)
        STATE.write_text(json.dumps({"pid": proc.pid, "argv": argv}))
        ready = wait_ready(notify, proc, start_timeout_s())
    shutil.rmtree(notify_dir)
    if not ready:
        print("Job for arbiterd.service failed because the control process exited with error "
              "code or did not become ready.", file=sys.stderr)
        return 1
    return 0


def wait_ready(notify: socket.socket, proc: subprocess.Popen[bytes], timeout_s: float) -> bool:
    """READY=1 from the service (True), or its exit or the start timeout (False)."""
    deadline = time.monotonic() + timeout_s
    notify.settimeout(0.1)
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return False
        try:
            message = notify.recv(4096)
        except TimeoutError:
            continue
        if b"READY=1" in message.split(b"\n"):
            return True
    return False


def stop() -> int:
    pid = running_pid()
    if pid is not None:
        os.kill(pid, signal.SIGTERM)
        deadline = time.monotonic() + STOP_TIMEOUT_S
        while alive(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        if alive(pid):
            os.kill(pid, signal.SIGKILL)
    if STATE.exists():
        stop_post()
        STATE.unlink()
    return 0


def stop_post() -> None:
    """ExecStopPost=, as systemd runs it after every stop."""
    if not unit_lines("ExecStopPost"):
        return
    env = environment()
    with LOG.open("ab") as log:
        rc = subprocess.call(command("ExecStopPost", env), stdout=log, stderr=log, env=env,
                             stdin=subprocess.DEVNULL, timeout=60)
    with CALLS.open("a") as calls:
        calls.write(f"ExecStopPost exit {rc}\n")


def state_word() -> str:
    if running_pid() is not None:
        return "active"
    return "failed" if STATE.exists() else "inactive"


def status() -> int:
    word = state_word()
    print(f"* arbiterd.service - fake systemd\n   Active: {word} {json.dumps(read_state())}")
    if LOG.exists():
        print("".join(LOG.read_text(errors="replace").splitlines(keepends=True)[-30:]))
    return 0 if word == "active" else 3


def injected_failure(verb: str) -> bool:
    marker = RUN / f"fail-{verb}"
    if not marker.exists():
        return False
    marker.unlink()
    print(f"Failed to {verb}: injected by the test ({marker})", file=sys.stderr)
    return True


def main(args: list[str]) -> int:
    CALLS.parent.mkdir(parents=True, exist_ok=True)
    with CALLS.open("a") as calls:
        calls.write(" ".join(args) + "\n")
    words = [a for a in args if not a.startswith("-")]
    verb, units = (words[0], words[1:]) if words else ("", [])
    if injected_failure(verb):
        return 1
    ours = bool(OURS.intersection(units))
    if verb in ("start", "restart", "stop") and not ours:
        return 0
    if verb == "start":
        return start()
    if verb == "restart":
        stop()
        return start()
    if verb == "stop":
        return stop()
    if verb == "is-active":
        return 0 if state_word() == "active" else 3
    if verb == "is-failed":
        return 0 if state_word() == "failed" else 1
    if verb == "status":
        return status()
    if verb in ("daemon-reload", "enable", "disable"):
        if "--now" in args and ours:
            return start() if verb == "enable" else stop()
        return 0
    print(f"fake systemctl: unsupported: {' '.join(args)}", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
