# `arbiterd record list|info`: the flight recorder's files, read on this machine.
from __future__ import annotations

import argparse
import json
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from daemon.components.recorder.files import RecordingIndex, RecordingInfo, inspect

EXIT_OK, EXIT_USAGE, EXIT_CONFIG = 0, 2, 78


def add_parser(sub: Any) -> argparse.ArgumentParser:
    record = sub.add_parser("record", help="the flight recorder's MCAP files")
    actions = record.add_subparsers(dest="record_command", required=True)
    listing = actions.add_parser("list", help="the recordings with size, start and duration")
    listing.add_argument("--config", help="config whose [recorder] directory to list "
                         "(default /etc/arbiterd/arbiterd.toml if present)")
    listing.add_argument("--dir", help="list this directory instead")
    listing.add_argument("--json", action="store_true", help="one JSON object per file")
    info = actions.add_parser("info", help="duration, topics and message counts of a file")
    info.add_argument("file", metavar="NAME|FILE",
                      help="a name `record list` prints (looked up in its directory) or a path")
    info.add_argument("--config", help="config whose [recorder] directory holds NAME "
                      "(default /etc/arbiterd/arbiterd.toml if present)")
    info.add_argument("--dir", help="look for NAME in this directory instead")
    info.add_argument("--json", action="store_true")
    return record


def needs_directory(args: argparse.Namespace) -> bool:
    """Whether the command looks in the recordings directory (not for `info` of a path)."""
    return args.record_command == "list" or not Path(args.file).is_file()


def run(args: argparse.Namespace, directory: Path) -> int:
    if args.record_command == "info":
        return _info(args.file, directory, args.json)
    return _list(directory, args.json)


def _info(name: str, directory: Path, as_json: bool) -> int:
    path = Path(name)
    if not path.is_file() and path.name == name and (directory / name).is_file():
        path = directory / name
    if not path.is_file():
        print(f"arbiterd record info: {name}: no such file here nor in {directory}; `arbiterd "
              "record list` prints the recordings' names (--dir DIR or --config FILE looks in "
              "another directory)", file=sys.stderr)
        return EXIT_USAGE
    info = inspect(path)
    if as_json:
        print(json.dumps(info.to_json()))
        return EXIT_OK
    print(format_info(path, info))
    return EXIT_OK


def format_info(path: Path, info: RecordingInfo) -> str:
    if info.complete:
        state = "complete"
    elif info.recording:
        state = ("being recorded: read up to its last whole chunk (the summary and index are "
                 "written when the file closes)")
    else:
        state = "not closed (writer stopped abruptly): read up to its last whole chunk"
    lines = [f"{path}: {info.size} bytes, {state}",
             f"  start     {_when(info.start_ns)}",
             f"  duration  {info.duration_s:.3f} s",
             f"  messages  {info.messages}"]
    width = max((len(t) for t in info.topics), default=5)
    for topic, t in sorted(info.topics.items()):
        lines.append(f"  {topic:<{width}}  {t.count:>8}  {t.type}")
    return "\n".join(lines)


def _list(directory: Path, as_json: bool) -> int:
    infos = RecordingIndex(directory).list()
    if as_json:
        for info in infos:
            print(json.dumps(info.to_json(topics=False)))
        return EXIT_OK
    if not infos:
        print(f"no recordings in {directory}")
        return EXIT_OK
    print(f"{directory}:")
    for info in infos:
        flag = "" if info.complete else (
            "  (being recorded)" if info.recording else "  (not closed)")
        print(f"  {info.name}  {info.size / 1e6:8.2f} MB  {_when(info.start_ns)}  "
              f"{info.duration_s:8.1f} s{flag}")
    return EXIT_OK


def _when(ns: int | None) -> str:
    if ns is None:
        return "-"
    return datetime.fromtimestamp(ns / 1e9, UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
