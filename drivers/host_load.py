# Whether this host is too busy to judge a device by its reply time: CPU pressure, load, lateness.
from __future__ import annotations

import os
from pathlib import Path

#: the share of the last 10 s in which some task waited for a CPU (Linux PSI) that makes the
#: host "busy": a reply that is late then may be ours, not the device's
PRESSURE_BUSY = 10.0
#: without PSI (an older kernel, some containers): the 1-minute load per core that does
LOAD_BUSY = 1.0
PRESSURE_FILE = Path("/proc/pressure/cpu")


def host_busy(pressure_file: Path = PRESSURE_FILE) -> str | None:
    """Why the CPUs are too busy to blame a device for a late reply, or None when they are not:
    the kernel's CPU pressure ("some avg10") where it has one, else the load average."""
    try:
        first = pressure_file.read_text().split("\n", 1)[0].split()
        share = float(dict(field.split("=", 1) for field in first[1:])["avg10"])
    except (OSError, ValueError, KeyError, IndexError):
        return _load_busy()
    if share >= PRESSURE_BUSY:
        return f"tasks waited for a CPU {share:.0f} % of the last 10 s"
    return None


def _load_busy() -> str | None:
    try:
        per_core = os.getloadavg()[0] / (os.cpu_count() or 1)
    except OSError:
        return None
    if per_core >= LOAD_BUSY:
        return f"load {per_core:.1f} per core"
    return None
