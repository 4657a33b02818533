# Zenoh configurations as plain dicts: the robot's session, and the operator's router with
# user-password authentication and the access control that keeps robots from commanding.
from __future__ import annotations

from pathlib import Path
from typing import Any

from daemon.components.fleet.keys import COMMAND, PREFIX

#: what a robot (any user that is not an operator) may not send into the router
_COMMAND_KEYS = [f"{PREFIX}/*/{COMMAND}/**"]


def robot_config(router: str, mode: str, user: str, password: str) -> dict[str, Any]:
    """A client (only the router, nothing listening) or a peer (the LAN too)."""
    config: dict[str, Any] = {
        "mode": mode,
        "connect": {"endpoints": [router] if router else []},
        "scouting": {"multicast": {"enabled": mode == "peer"}},
    }
    if mode == "peer":
        config["listen"] = {"endpoints": ["tcp/0.0.0.0:0"]}
    if user:
        config["transport"] = {"auth": {"usrpwd": {"user": user, "password": password}}}
    return config


def router_config(listen: str, users_file: Path | None,
                  operators: list[str]) -> dict[str, Any]:
    """The operator's router. With a users file, a session without a listed user and
    password is refused, and users who are not operators may not query or put command keys."""
    config: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": [listen]},
        "scouting": {"multicast": {"enabled": False}},
    }
    if users_file is None:
        return config
    config["transport"] = {"auth": {"usrpwd": {"dictionary_file": str(users_file)}}}
    robots = sorted(users(users_file) - set(operators))
    if robots:
        config["access_control"] = {
            "enabled": True, "default_permission": "allow",
            "rules": [{"id": "no-commands", "permission": "deny", "flows": ["ingress"],
                       "messages": ["put", "delete", "query"], "key_exprs": _COMMAND_KEYS}],
            "subjects": [{"id": "robots", "usernames": robots}],
            "policies": [{"rules": ["no-commands"], "subjects": ["robots"]}],
        }
    return config


def users(users_file: Path) -> set[str]:
    """The user names of a Zenoh dictionary file (``user:password`` per line)."""
    names = set()
    for line in users_file.read_text().splitlines():
        name, sep, _ = line.partition(":")
        if sep and name.strip():
            names.add(name.strip())
    return names


def read_secret(value: str, path: str) -> str:
    """A password given inline, or the first line of its file."""
    if value or not path:
        return value
    lines = Path(path).read_text().splitlines()
    return lines[0].strip() if lines else ""
