# The mock driver's wheel log (its ``log_file``): what its "hardware" was told, from any process.
from __future__ import annotations

from pathlib import Path


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
