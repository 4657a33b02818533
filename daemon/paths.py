# Where the daemon keeps what it makes: the service's state directory, else the XDG state dir.
from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

#: StateDirectory=arbiterd of the systemd unit
SERVICE_STATE = Path("/var/lib/arbiterd")


def state_directory(sub: str, env: Mapping[str, str] | None = None) -> Path:
    """``sub`` in systemd's StateDirectory when there is one, else in the XDG state dir."""
    env = os.environ if env is None else env
    state = env.get("STATE_DIRECTORY", "").split(":")[0]
    if state:
        return Path(state) / sub
    xdg = env.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(xdg) / "arbiterd" / sub


def listing_directory(configured: str, sub: str,
                      env: Mapping[str, str] | None = None) -> Path:
    """Where a command run from a shell looks: as the daemon would, except that without
    $STATE_DIRECTORY the installed service's directory wins when it exists."""
    env = os.environ if env is None else env
    if configured:
        return Path(configured).expanduser()
    service = SERVICE_STATE / sub
    if not env.get("STATE_DIRECTORY") and service.is_dir():
        return service
    return state_directory(sub, env)
