#!/usr/bin/env python3
# A recording systemctl for a fake Pi root: runs arbiterd.service's ExecStart inside the root.
#
# Environment: FAKE_SYSTEMD_ROOT (the fake Pi's root). Every call is appended to
# <root>/var/log/systemctl.log; the service's output goes to <root>/var/log/arbiterd.log and its
# state to <root>/run/fake-systemd/arbiterd.json. Absolute paths in the unit's command lines are
# taken inside the root, and $VARS come from its EnvironmentFile, as systemd would expand them.
from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(os.environ["FAKE_SYSTEMD_ROOT"])
UNIT = ROOT / "etc/systemd/system/arbiterd.service"
STATE = ROOT / "run/fake-systemd/arbiterd.json"
LOG = ROOT / "var/log/arbiterd.log"
CALLS = ROOT / "var/log/systemctl.log"
STOP_TIMEOUT_S = 10.0


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
    return env


def command(key: str, env: dict[str, str]) -> list[str]:
    """The unit's command line: -/@ prefixes dropped, $VAR split into words, paths in ROOT."""
    words: list[str] = []
    for word in shlex.split(unit_lines(key)[0]):
        if word.startswith("$"):
            words += env.get(word.strip("${}"), "").split()
        else:
            words.append(word)
    words[0] = words[0].lstrip("-@:+!")
    return [str(ROOT / w.lstrip("/")) if w.startswith("/") else w for w in words]


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


def start() -> int:
    if running_pid() is not None:
        return 0
    env = environment()
    argv = command("ExecStart", env)
    LOG.parent.mkdir(parents=True, exist_ok=True)
    STATE.parent.mkdir(parents=True, exist_ok=True)
    with LOG.open("ab") as log:
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=log, env=env,
                                cwd=ROOT, start_new_session=True)
    STATE.write_text(json.dumps({"pid": proc.pid, "argv": argv}))
    return 0


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


def main(args: list[str]) -> int:
    CALLS.parent.mkdir(parents=True, exist_ok=True)
    with CALLS.open("a") as calls:
        calls.write(" ".join(args) + "\n")
    words = [a for a in args if not a.startswith("-")]
    verb, units = (words[0], words[1:]) if words else ("", [])
    ours = "arbiterd.service" in units or "arbiterd" in units
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
        if "--now" in args and verb == "disable" and ours:
            stop()
        return 0
    print(f"fake systemctl: unsupported: {' '.join(args)}", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
