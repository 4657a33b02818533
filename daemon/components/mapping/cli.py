# `arbiterd map save|list|build`: maps from a running daemon, on this machine, or a recording.
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from daemon.api_client import api_failure, call_api
from daemon.components.mapping.mapfile import save_map, saved_maps
from daemon.components.mapping.settings import MappingSettings, map_name_error

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


def add_parser(sub: Any) -> argparse.ArgumentParser:
    parser = sub.add_parser("map", help="maps: save the running daemon's, list the saved "
                            "ones, build one from a recording")
    actions = parser.add_subparsers(dest="map_command", required=True)
    save = actions.add_parser("save", help="save the running daemon's map as NAME "
                              "(POST /api/map/save)")
    save.add_argument("name", help="the map's name: letters, digits, _ - . (its files are "
                      "NAME.pgm and NAME.yaml)")
    save.add_argument("--url", help="the daemon's address (default: from the config)")
    save.add_argument("--config", help="config file (its [http] address and token)")
    listing = actions.add_parser("list", help="the saved maps")
    listing.add_argument("--config", help="config whose [mapping] directory to list")
    listing.add_argument("--dir", help="list this directory instead")
    listing.add_argument("--json", action="store_true")
    build = actions.add_parser("build", help="build a map offline from a recording (.mcap "
                               "from arbiterd, or a ROS 1 .bag / CARMEN .clf log)")
    build.add_argument("recording", help="the log to build from: the path of an arbiterd "
                       "recording (.mcap), a ROS 1 .bag or a CARMEN .clf file")
    build.add_argument("--name", help="map name (default: the recording's name)")
    build.add_argument("--dir", help="write the map here (default: the [mapping] directory)")
    build.add_argument("--config", help="config whose [mapping] settings to use")
    build.add_argument("--csv", help="also write the corrected trajectory to this CSV file")
    build.add_argument("--refine", action="store_true",
                       help="also run the offline stages (final optimisation, returns after a "
                       "long tour, every pose polished): slower, more accurate")
    return parser


def run_list(directory: Path, as_json: bool) -> int:
    maps = saved_maps(directory)
    if as_json:
        for entry in maps:
            print(json.dumps(entry))
        return EXIT_OK
    if not maps:
        print(f"no maps in {directory}")
        return EXIT_OK
    for entry in maps:
        when = time.strftime("%Y-%m-%d %H:%M", time.localtime(entry["modified"]))
        if "error" in entry:
            print(f"{entry['name']:<24} {when}  unreadable: {entry['error']}")
        else:
            size = f"{entry['width']} x {entry['height']} cells"
            print(f"{entry['name']:<24} {when}  {size} at {entry['resolution']:g} m")
    return EXIT_OK


def run_build(args: argparse.Namespace, settings: MappingSettings, directory: Path) -> int:
    from daemon.components.mapping.build import RecordingError, build_map, write_trajectory
    from slam.mapper import MapperConfig

    recording = Path(args.recording)
    name = args.name or recording.stem.replace(".", "-")
    problem = map_name_error(name)
    if problem:
        print(f"arbiterd map build: {problem}; pass --name NAME", file=sys.stderr)
        return EXIT_USAGE
    config = MapperConfig(resolution=settings.resolution, max_range=settings.max_range_m,
                          loop_closure=settings.loop_closure,
                          max_cells=int((settings.max_size_m / settings.resolution) ** 2))
    try:
        result = build_map(recording, config, refine=args.refine)
    except RecordingError as exc:
        print(f"arbiterd map build: {exc}", file=sys.stderr)
        return EXIT_FAILED
    _, yml = save_map(directory, name, result.grid)
    print(f"map {name}: {result.grid.width} x {result.grid.height} cells at "
          f"{result.grid.resolution:g} m from {result.used} revolutions "
          f"({result.matched} matched) -> {yml}")
    if result.far_loops is not None:
        print(f"refined: {result.far_loops['far_accepted']} returns after a long tour closed "
              f"({result.far_loops['far_candidates']} candidates), every pose polished")
    if args.csv:
        write_trajectory(Path(args.csv), result.trajectory)
        print(f"trajectory: {len(result.trajectory)} poses -> {args.csv}")
    return EXIT_OK


def run_save(name: str, base: str, token: str) -> int:
    problem = map_name_error(name)
    if problem:
        print(f"arbiterd map save: {problem}", file=sys.stderr)
        return EXIT_USAGE
    try:
        body = call_api(base, token, "POST", "/api/map/save", {"name": name})
    except (OSError, ValueError) as exc:  # a refusal, no answer, or an answer not JSON
        reason = api_failure(base, exc) if isinstance(exc, OSError) else f"bad answer: {exc}"
        print(f"arbiterd map save: {reason}", file=sys.stderr)
        return EXIT_FAILED
    print(f"map {body['name']}: {body['width']} x {body['height']} cells at "
          f"{body['resolution']:g} m saved as {body['yaml']} + {body['image']}")
    return EXIT_OK
