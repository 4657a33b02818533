# Why a serial or TCP port is not ours, in words that say what to do: who holds it, what is there.
from __future__ import annotations

import errno
import glob
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

#: where USB serial adapters and Arduino-like boards show up
CANDIDATE_PATTERNS = ("/dev/ttyUSB*", "/dev/ttyACM*", "/dev/serial/by-id/*")
DIALOUT_HINT = ("the user running arbiterd needs the dialout group to open serial ports "
                "(sudo usermod -aG dialout $USER, then log in again)")
PROC = Path("/proc")
#: the interpreter itself (``python3``, ``python3.11``, ``/usr/bin/python``), not a script
_PYTHON = re.compile(r"python[0-9.]*")
#: interpreter options that take a value (``-W error``, ``-X dev``, ``-m mod``, ``-c code``)
_PYTHON_VALUE_LETTERS = "WXmc"
_PYTHON_LONG_VALUE_OPTIONS = ("--check-hash-based-pycs",)
DAEMON_MODULE = "daemon.cli"


@dataclass(frozen=True)
class Holder:
    """A process holding a port: its pid, a name to show, and whether it is the daemon."""

    pid: int
    name: str
    daemon: bool = False

    def __str__(self) -> str:
        return f"{self.name} (pid {self.pid})"


def arbiterd_command(argv: Sequence[str]) -> str | None:
    """The sub-command of an ``arbiterd`` command line (``run``, ``lidar``, ...; ``""`` for
    none), or None when ``argv`` is not arbiterd at all. arbiterd is the ``arbiterd`` console
    script (run directly or through its interpreter, as a shebang does) or ``python -m
    daemon.cli``; a path that merely contains "arbiterd" (a clone, a venv) is not."""
    if not argv:
        return None
    rest: Sequence[str]
    if _PYTHON.fullmatch(os.path.basename(argv[0])):
        found = _python_target(argv[1:])
        if found is None:
            return None
        target, rest = found
        if target != DAEMON_MODULE and os.path.basename(target) != "arbiterd":
            return None
    elif os.path.basename(argv[0]) == "arbiterd":
        rest = argv[1:]
    else:
        return None
    return next((arg for arg in rest if not arg.startswith("-")), "")


def _python_target(args: Sequence[str]) -> tuple[str, Sequence[str]] | None:
    """(the module after ``-m`` or the script, the arguments after it) of a Python command
    line without its interpreter; None for ``-c CODE`` or a bare interpreter. Short options
    combine as Python parses them (``-Bm daemon.cli``, ``-Wignore``)."""
    i = 0
    while i < len(args):
        arg = args[i]
        if arg == "--" or not arg.startswith("-") or arg == "-":
            at = i + 1 if arg == "--" else i
            return (args[at], args[at + 1:]) if at < len(args) else None
        i += 1
        if arg.startswith("--"):
            i += arg in _PYTHON_LONG_VALUE_OPTIONS
            continue
        for j, letter in enumerate(arg[1:], start=2):
            if letter in _PYTHON_VALUE_LETTERS:
                value = arg[j:]
                if not value:
                    value = args[i] if i < len(args) else ""
                    i += 1
                if letter == "c":
                    return None
                if letter == "m":
                    return value, args[i:]
                break
    return None


def is_daemon(argv: Sequence[str]) -> bool:
    """``argv`` is the daemon: ``arbiterd run`` (the service, ``./install.sh sim``)."""
    return arbiterd_command(argv) == "run"


def command_line(pid: int, proc: Path = PROC) -> list[str] | None:
    """The argv of ``pid`` from /proc (None when it is gone or not ours to read)."""
    try:
        raw = (proc / str(pid) / "cmdline").read_bytes()
    except OSError:
        return None
    return [arg.decode(errors="replace") for arg in raw.split(b"\0")[:-1]] if raw else []


def holder(pid: int, proc: Path = PROC) -> Holder:
    """Who ``pid`` is: ``arbiterd`` for the daemon (however it was started), ``arbiterd
    <command>`` for another arbiterd command, else the process name."""
    argv = command_line(pid, proc)
    command = arbiterd_command(argv) if argv else None
    if command == "run":
        return Holder(pid, "arbiterd", daemon=True)
    if command is not None:
        return Holder(pid, f"arbiterd {command}".strip())
    try:
        name = (proc / str(pid) / "comm").read_text().strip()
    except OSError:
        name = ""
    return Holder(pid, name or "a process")


def _holding(targets: set[str], proc: Path) -> list[Holder]:
    """Every other process with one of ``targets`` (fd link texts) open, the daemon first."""
    found: list[Holder] = []
    if not targets:
        return found
    for fd_dir in proc.glob("[0-9]*/fd"):
        pid = int(fd_dir.parent.name)
        if pid == os.getpid():
            continue
        try:
            links = {os.readlink(fd) for fd in fd_dir.iterdir()}
        except OSError:  # gone, or not ours to look at
            continue
        if targets & links:
            found.append(holder(pid, proc))
    return sorted(found, key=lambda h: (not h.daemon, h.pid))


def holders(device: str | Path, proc: Path = PROC) -> list[Holder]:
    """Every other process with ``device`` open, found via /proc/*/fd, the daemon first."""
    try:
        target = os.path.realpath(device)
    except OSError:
        return []
    return _holding({target}, proc)


def listeners(port: int, proc: Path = PROC) -> list[Holder]:
    """Every other process listening on TCP ``port`` (IPv4 or IPv6), the daemon first. A
    process of another user is not found (its /proc/*/fd is not ours to read)."""
    return _holding({f"socket:[{inode}]" for inode in _listening_inodes(port, proc)}, proc)


def _listening_inodes(port: int, proc: Path) -> Iterable[str]:
    for table in ("tcp", "tcp6"):
        try:
            lines = (proc / "net" / table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            # sl local_address rem_address st ... inode; st 0A is LISTEN
            if len(fields) > 9 and fields[3] == "0A" and \
                    int(fields[1].rsplit(":", 1)[1], 16) == port:
                yield fields[9]


def busy_message(device: str | Path) -> str | None:
    """"arbiterd (pid N) is using /dev/x — ..." when another process has ``device`` open."""
    found = holders(device)
    if not found:
        return None
    first = found[0]
    if first.daemon:
        return (f"{first} is using {device} — stop the service (sudo systemctl "
                "stop arbiterd) or use `arbiterd status`")
    return f"{first} is using {device} — close it first"


def candidates() -> list[str]:
    """Serial devices present now."""
    return sorted({path for pattern in CANDIDATE_PATTERNS for path in glob.glob(pattern)})


def missing_message(device: str | Path) -> str:
    present = candidates()
    listed = ", ".join(present) if present else "none (is the board plugged in and powered?)"
    return f"{device} does not exist; serial devices present: {listed}; {DIALOUT_HINT}"


def open_error(device: str | Path, exc: BaseException) -> str:
    """Why opening ``device`` failed (an OSError or pyserial's SerialException), and what to
    do; a caller puts "cannot open <device>: " in front."""
    code = getattr(exc, "errno", None)
    text = str(exc)
    if code in (errno.EBUSY, errno.EAGAIN) or "exclusively lock" in text:
        return busy_message(device) or (
            f"another process has locked {device} (one this user may not see); if it is the "
            "arbiterd service: stop it (sudo systemctl stop arbiterd) or use `arbiterd status`")
    if code == errno.ENOENT or "No such file or directory" in text or not os.path.exists(device):
        return missing_message(device)
    if code == errno.EACCES or "Permission denied" in text:
        return f"permission denied; {DIALOUT_HINT}"
    return text
