# Where the flight recorder's files go: [recorder] directory, or the service's state directory.
from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from daemon import paths

SERVICE_DIRECTORY = paths.SERVICE_STATE / "recordings"


def default_directory(env: Mapping[str, str] | None = None) -> Path:
    """recordings/ in systemd's StateDirectory when there is one, else in the XDG state dir."""
    return paths.state_directory("recordings", env)


def record_directory(options: Mapping[str, object]) -> Path:
    configured = str(options.get("directory") or "")
    return Path(configured).expanduser() if configured else default_directory()


def listing_directory(options: Mapping[str, object],
                      env: Mapping[str, str] | None = None) -> Path:
    """Where `arbiterd record list` looks: as the daemon would, except that from a shell
    (no $STATE_DIRECTORY) the installed service's recordings win when they exist."""
    env = os.environ if env is None else env
    if not options.get("directory") and not env.get("STATE_DIRECTORY") and (
            SERVICE_DIRECTORY.is_dir()):
        return SERVICE_DIRECTORY
    return record_directory(options)
