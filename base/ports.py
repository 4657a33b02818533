# Why a serial port does not open, in words that say what to do: who holds it, what is there.
from __future__ import annotations

import errno
import glob
import os
from pathlib import Path

#: where USB serial adapters and Arduino-like boards show up
CANDIDATE_PATTERNS = ("/dev/ttyUSB*", "/dev/ttyACM*", "/dev/serial/by-id/*")
DIALOUT_HINT = ("the user running arbiterd needs the dialout group to open serial ports "
                "(sudo usermod -aG dialout $USER, then log in again)")


def holders(device: str | Path, proc: Path = Path("/proc")) -> list[tuple[int, str]]:
    """(pid, program) of every other process with ``device`` open, found via /proc/*/fd."""
    try:
        target = os.path.realpath(device)
    except OSError:
        return []
    found = []
    for fd_dir in proc.glob("[0-9]*/fd"):
        pid = int(fd_dir.parent.name)
        if pid == os.getpid():
            continue
        try:
            links = [os.readlink(fd) for fd in fd_dir.iterdir()]
        except OSError:  # gone, or not ours to look at
            continue
        if target in links:
            found.append((pid, program(pid, proc)))
    return found


def program(pid: int, proc: Path = Path("/proc")) -> str:
    """``arbiterd`` for our own daemon (however it was started), else the process name."""
    try:
        cmdline = (proc / str(pid) / "cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return "a process"
    if "arbiterd" in cmdline or "daemon.cli" in cmdline:
        return "arbiterd"
    try:
        return (proc / str(pid) / "comm").read_text().strip() or "a process"
    except OSError:
        return "a process"


def busy_message(device: str | Path) -> str | None:
    """"arbiterd (pid N) is using /dev/x — ..." when another process has ``device`` open."""
    found = sorted(holders(device), key=lambda holder: holder[1] != "arbiterd")
    if not found:
        return None
    pid, name = found[0]
    if name == "arbiterd":
        return (f"arbiterd (pid {pid}) is using {device} — stop the service (sudo systemctl "
                "stop arbiterd) or use `arbiterd status`")
    return f"{name} (pid {pid}) is using {device} — close it first"


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
