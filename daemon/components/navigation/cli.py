# `arbiterd mission FILE`: a mission from a TOML or JSON file, run by the running daemon.
from __future__ import annotations

import argparse
import json
import sys
import time
import tomllib
import urllib.error
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from daemon.api_client import api_failure, call_api
from daemon.components.navigation.messages import GoalError
from daemon.components.navigation.mission import mission_of_json

EXIT_OK, EXIT_FAILED = 0, 1
#: as `arbiterd status`: no daemon answers
EXIT_UNAVAILABLE = 69
#: how often the mission's progress is read while waiting for it (s)
POLL_S = 0.5

#: GET or POST a path of the daemon's API (``body`` None: GET): the JSON answer
Fetch = Callable[[str, str, "dict[str, Any] | None"], "dict[str, Any]"]


class MissionFileError(ValueError):
    """The file cannot be read, or a step in it is not a goal; says where."""


def add_parser(sub: Any) -> argparse.ArgumentParser:
    parser = sub.add_parser(
        "mission", help="run a mission from a TOML or JSON file on the running daemon "
        "(POST /api/mission) and print each step's result",
        description="Run the goals of FILE one after another on the running daemon. FILE is "
        "TOML (name = \"tour\", then one [[steps]] table per goal) or JSON ({\"name\": ..., "
        "\"steps\": [...]}); each step is what POST /api/goal takes. Every step is checked "
        "before anything is sent.")
    parser.add_argument("file", help="the mission: .toml or .json")
    parser.add_argument("--url", help="the daemon's address (default: from the config)")
    parser.add_argument("--config", help="config file (its [http] address and token)")
    parser.add_argument("--no-wait", action="store_true",
                        help="start the mission and return; do not wait for its steps")
    return parser


def load_mission_file(path: Path) -> dict[str, Any]:
    """The mission in ``path`` as POST /api/mission's body, every step checked: a
    MissionFileError names the file and the step and field at fault."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise MissionFileError(f"{path}: cannot read it: {exc}") from None
    as_json = path.suffix.lower() == ".json"
    try:
        body = json.loads(text) if as_json else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        kind = "JSON" if as_json else "TOML"
        raise MissionFileError(f"{path}: not valid {kind}: {exc}") from None
    if not isinstance(body, dict):
        raise MissionFileError(f"{path}: expected an object with \"steps\"")
    body.setdefault("name", path.stem[:64] or "mission")
    try:
        mission_of_json(body, "odom")  # the frame the daemon fills in does not matter here
    except GoalError as exc:
        raise MissionFileError(f"{path}: {exc}") from None
    return body


def http_fetch(base: str, token: str) -> Fetch:
    def fetch(method: str, path: str, body: dict[str, Any] | None) -> dict[str, Any]:
        return call_api(base, token, method, path, body)
    return fetch


def run_mission(file: str, base: str, token: str, *, wait: bool = True,
                fetch: Fetch | None = None, out: TextIO = sys.stdout,
                sleep: Callable[[float], None] = time.sleep) -> int:
    """Check the file, start the mission, then (``wait``) print each step's result as it
    ends; 0 when every step succeeded."""
    try:
        body = load_mission_file(Path(file))
    except MissionFileError as exc:
        print(f"arbiterd mission: {exc}", file=sys.stderr)
        return EXIT_FAILED
    fetch = fetch or http_fetch(base, token)
    try:
        status = fetch("POST", "/api/mission", body)
        mission = status.get("mission") or {}
        print(f"mission {mission.get('name', body['name'])!r}: {len(body['steps'])} steps "
              "started", file=out, flush=True)
        if not wait:
            return EXIT_OK
        return _follow(fetch, mission, out, sleep)
    except OSError as exc:  # urllib's HTTPError (a refusal) and URLError are OSErrors
        print(f"arbiterd mission: {api_failure(base, exc)}", file=sys.stderr)
        return EXIT_FAILED if isinstance(exc, urllib.error.HTTPError) else EXIT_UNAVAILABLE
    except KeyboardInterrupt:  # the robot stops with the one who started it
        try:
            fetch("DELETE", "/api/goal", None)
        except (urllib.error.URLError, OSError):
            print("arbiterd mission: interrupted, and the daemon did not answer the cancel: "
                  "the mission may still run (DELETE /api/goal)", file=sys.stderr)
        else:
            print("arbiterd mission: interrupted; the mission was canceled", file=sys.stderr)
        return EXIT_FAILED


def _follow(fetch: Fetch, mission: dict[str, Any], out: TextIO,
            sleep: Callable[[float], None]) -> int:
    """Print each step's result as it ends, until the mission ends."""
    printed = 0
    while True:
        results = mission.get("results", [])
        while printed < len(results) and results[printed]["state"] not in ("pending",
                                                                          "running"):
            print(_step_line(printed, len(results), results[printed]), file=out, flush=True)
            printed += 1
        if mission.get("state") != "running":
            break
        sleep(POLL_S)
        mission = fetch("GET", "/api/goal", None).get("mission") or {}
    state = mission.get("state", "gone")
    reason = f": {mission['reason']}" if mission.get("reason") else ""
    print(f"mission {mission.get('name')!r} {state}{reason}", file=out, flush=True)
    return EXIT_OK if state == "succeeded" else EXIT_FAILED


def _step_line(index: int, steps: int, result: dict[str, Any]) -> str:
    elapsed = f" in {result['elapsed_s']:g} s" if "elapsed_s" in result else ""
    reason = f": {result['reason']}" if result.get("reason") else ""
    return f"step {index + 1}/{steps} {result['state']}{elapsed}{reason}"
