# Helpers shared by the systemd, install.sh and deploy-pi.sh tests (unit parsing, paths).
from __future__ import annotations

import json
from pathlib import Path

from tests.support.paths import REPO

SYSTEMD_DIR = REPO / "systemd"
INSTALL_SH = REPO / "install.sh"
DEPLOY_SH = REPO / "deploy-pi.sh"


def parse_unit(text: str) -> list[tuple[str, str, str]]:
    """Return (section, key, value) for every assignment of a unit file, in order."""
    entries: list[tuple[str, str, str]] = []
    section = ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1]
            continue
        key, sep, value = line.partition("=")
        if not sep:
            raise ValueError(f"not an assignment in section [{section}]: {raw!r}")
        entries.append((section, key.strip(), value.strip()))
    return entries


def unit_values(text: str, section: str, key: str) -> list[str]:
    """Every value assigned to section.key, in order (repeatable keys give several)."""
    return [v for s, k, v in parse_unit(text) if s == section and k == key]


def fake_service_pid(state_dir: Path) -> int | None:
    """The pid of the daemon fake_systemctl.py started, from its state in ``state_dir``
    (its FAKE_SYSTEMD_STATE); None while it has not started one."""
    state = state_dir / "arbiterd.json"
    if not state.exists():
        return None
    pid: int = json.loads(state.read_text())["pid"]
    return pid
