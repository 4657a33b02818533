# Where the flight recorder's files go: [record] directory, or the service's state directory.
from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path


def default_directory(env: Mapping[str, str] | None = None) -> Path:
    """recordings/ in systemd's StateDirectory when there is one, else in the XDG state dir."""
    env = os.environ if env is None else env
    state = env.get("STATE_DIRECTORY", "").split(":")[0]
    if state:
        return Path(state) / "recordings"
    xdg = env.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(xdg) / "arbiterd" / "recordings"


def record_directory(options: Mapping[str, object]) -> Path:
    configured = str(options.get("directory") or "")
    return Path(configured).expanduser() if configured else default_directory()
