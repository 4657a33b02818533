# `arbiterd simulate`: options -> a lockstep run -> the run metrics as a table or JSON.
from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import sys
from pathlib import Path
from typing import Any

from daemon.config import Config, ConfigError, load_config
from daemon.lockstep.runner import Lockstep
from daemon.lockstep.script import ScriptError, load_script
from sim.settings import SimConfigError
from sim.world import WorldError

EXIT_OK, EXIT_USAGE, EXIT_CONFIG = 0, 2, 78


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p: argparse.ArgumentParser = sub.add_parser(
        "simulate", help="run the control loop, safety, autonomy and the simulated world in "
        "lockstep virtual time, faster than real time; print the run metrics")
    p.add_argument("--seconds", type=float, help="simulated seconds to run (required unless "
                   "--goals or --explore)")
    p.add_argument("--seed", type=int, help="[sim] seed: obstacle placement, noise, wander")
    p.add_argument("--world", help="world file (.toml or .json) or built-in world name "
                   "(apartment, warehouse, loop) instead of the seeded arena")
    p.add_argument("--autonomy", choices=("wander",), help="start the wander behaviour")
    p.add_argument("--script", help="timed commands and events to replay (.toml or .json)")
    p.add_argument("--json", action="store_true", help="print the metrics as one JSON object")
    p.add_argument("--csv", help="stream the run metrics to this CSV file")
    p.add_argument("--config", help="take [robot], [limits], [control], [collision_monitor], "
                   "[autonomy] and [sim] from this config file (default: built-in defaults)")
    p.add_argument("--mapping", action="store_true", help="run the mapper on the simulated "
                   "lidar and report its pose error and map quality against the true world, "
                   "beside odometry alone")
    p.add_argument("--map-out", metavar="PATH", help="with --mapping: save the map as "
                   "PATH.yaml + PATH.pgm")
    p.add_argument("--goals", type=int, metavar="N", help="navigation instead of a timed run: "
                   "drive to N random reachable goals of --world (and --unreachable ones) from "
                   "an empty costmap, judged by ground truth; print each goal and a summary")
    p.add_argument("--unreachable", type=int, default=0, metavar="M", help="with --goals: "
                   "also M goals inside obstacles or closed spaces (each must fail)")
    p.add_argument("--drift", action="store_true", help="with --goals: a base that drifts "
                   "(2 %% calibration errors, 2 %% slip, 5 %% lidar dropouts); add --mapping "
                   "to send the goals in the map frame")
    p.add_argument("--explore", action="store_true", help="frontier exploration instead of a "
                   "timed run: the autonomy's mode explore from an empty costmap in --world (by "
                   "default apartment, then warehouse) until it is done; print per world the "
                   "share of the reachable free area known (ground truth), the time and the "
                   "collisions")
    p.add_argument("--fetch", type=int, metavar="N", help="fetch missions instead of a "
                   "timed run: N random object and drop points of --world (default warehouse) "
                   "over seeds 1-5 (or --seed), each fetched and delivered by the arm and "
                   "navigation, judged by the simulated object's true position")
    p.add_argument("--localise", type=int, metavar="N", help="global localisation instead of "
                   "a timed run: N random starts on --world's map (default: each of "
                   "apartment, warehouse and loop) with no pose given, the robot driving on "
                   "while the place is ambiguous; judged by the true pose (found within "
                   "0.10 m and 5 deg, ambiguous, confidently wrong; median time to a sure "
                   "pose)")
    p.add_argument("--kidnap", action="store_true", help="with --localise: once the first "
                   "pose is sure, each start is an untold teleport (a carry); also reports "
                   "how many were noticed and the median time to notice")
    p.add_argument("--dock", type=int, metavar="N", help="dockings instead of a timed run: N "
                   "times drive to a random pose of --world (default apartment and warehouse, "
                   "N each), then go home to its dock, on a base that drifts, mapping on; "
                   "judged against the true dock")
    p.add_argument("--day", type=float, metavar="HOURS", help="a day in the life: HOURS "
                   "simulated hours of missions (goals and fetches) in the warehouse on the "
                   "simulated battery; the robot goes home by itself, charges and resumes; "
                   "beside the same missions on an infinite battery")
    p.add_argument("--verbose", action="store_true", help="log every safety and autonomy "
                   "change to stderr")
    return p


def run(args: argparse.Namespace) -> int:
    logging.getLogger().setLevel(logging.INFO if args.verbose else logging.WARNING)
    if args.goals is not None:
        return run_goals(args)
    if args.explore:
        return run_explore(args)
    if args.fetch is not None:
        return run_fetch(args)
    if args.localise is not None:
        return run_localise(args)
    if args.dock is not None:
        return run_dock(args)
    if args.day is not None:
        return run_day(args)
    if args.seconds is None or not args.seconds > 0:
        print("arbiterd simulate: --seconds must be > 0", file=sys.stderr)
        return EXIT_USAGE
    try:
        script = load_script(args.script) if args.script else []
    except ScriptError as exc:
        print(f"arbiterd simulate: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        config = _config(args)
        runner = Lockstep(config, script=script, autonomy=args.autonomy,
                          mapping=args.mapping, map_out=args.map_out)
    except ConfigError as exc:
        for problem in exc.problems:
            print(f"arbiterd simulate: {problem}", file=sys.stderr)
        return EXIT_CONFIG
    except (SimConfigError, WorldError, OSError, ValueError) as exc:
        print(f"arbiterd simulate: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    result = asyncio.run(runner.run(args.seconds))
    print(json.dumps(result) if args.json else format_report(result))
    return EXIT_OK


def run_goals(args: argparse.Namespace) -> int:
    """``--goals N``: the navigation benchmark's run for one world and seed."""
    from daemon.lockstep.navigation import NavigationRun, summarise

    if args.goals < 1 or args.unreachable < 0 or not args.world:
        print("arbiterd simulate: --goals needs N >= 1 and a --world", file=sys.stderr)
        return EXIT_USAGE
    try:
        run = NavigationRun(args.world, args.seed or 1, reachable=args.goals,
                            unreachable=args.unreachable, mapping=args.mapping,
                            drift=args.drift)
    except (ConfigError, SimConfigError, WorldError, OSError, ValueError) as exc:
        print(f"arbiterd simulate: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    rows = asyncio.run(run.run())
    summary = summarise(rows)
    if args.json:
        print(json.dumps({"goals": rows, "summary": summary}))
        return EXIT_OK
    for r in rows:
        print(f"  {r['state']:<9} goal ({r['goal'][0]:6.2f}, {r['goal'][1]:6.2f}) "
              f"{'reachable  ' if r['reachable'] else 'unreachable'} {r['seconds']:6.1f} s "
              f"error {r.get('error_m', 0):.3f} m path {r.get('path_m', 0):.2f} m "
              f"ratio {r.get('ratio')} {r['reason']}")
    print(json.dumps(summary["all"]))
    return EXIT_OK


def run_explore(args: argparse.Namespace) -> int:
    """``--explore``: an exploration per world (``--world``, else apartment and warehouse)."""
    from daemon.lockstep.explore import WORLDS, explore_run, format_row

    rows = []
    for world in [args.world] if args.world else list(WORLDS):
        try:
            rows.append(asyncio.run(explore_run(world, args.seed or 1)))
        except (ConfigError, SimConfigError, WorldError, OSError, ValueError) as exc:
            print(f"arbiterd simulate: {exc}", file=sys.stderr)
            return EXIT_CONFIG
        if not args.json:
            print(format_row(rows[-1]), flush=True)
    if args.json:
        print(json.dumps({"explorations": rows}))
    return EXIT_OK


def run_localise(args: argparse.Namespace) -> int:
    """``--localise N``: N starts with no pose per world; the last line sums them up."""
    from daemon.lockstep.localise import WORLDS, localise_world, summarise

    if args.localise < 1:
        print("arbiterd simulate: --localise needs N >= 1", file=sys.stderr)
        return EXIT_USAGE
    rows: list[dict[str, Any]] = []
    for world in [args.world] if args.world else list(WORLDS):
        try:
            trials = localise_world(world, args.localise, args.seed or 1, args.kidnap)
        except (ConfigError, SimConfigError, WorldError, OSError, ValueError) as exc:
            print(f"arbiterd simulate: {exc}", file=sys.stderr)
            return EXIT_CONFIG
        for r in trials:
            rows.append(r)
            if args.json:
                print(json.dumps(r), flush=True)
            else:
                print(f"  {r['world']:<10} {r['outcome']:<9} truth ({r['truth'][0]:6.2f}, "
                      f"{r['truth'][1]:6.2f}, {math.degrees(r['truth'][2]):6.1f} deg) "
                      f"{r['seconds']:6.2f} s, {r.get('revolutions', '-')} revolutions, error "
                      f"{r.get('error_m', math.nan):.3f} m / {r.get('error_deg', math.nan):.2f}"
                      " deg", flush=True)
    print(json.dumps(summarise(rows)))
    return EXIT_OK


def run_fetch(args: argparse.Namespace) -> int:
    """``--fetch N``: N fetch missions over seeds 1-5 (or the one --seed)."""
    from daemon.lockstep.fetch import FetchRun, summarise

    if args.fetch < 1:
        print("arbiterd simulate: --fetch needs N >= 1", file=sys.stderr)
        return EXIT_USAGE
    seeds = [args.seed] if args.seed is not None else [1, 2, 3, 4, 5]
    counts = [args.fetch // len(seeds) + (i < args.fetch % len(seeds))
              for i in range(len(seeds))]
    rows: list[dict[str, Any]] = []
    for seed, count in zip(seeds, counts, strict=True):
        if not count:
            continue
        try:
            run = FetchRun(args.world or "warehouse", seed, count)
        except (ConfigError, SimConfigError, WorldError, OSError, ValueError) as exc:
            print(f"arbiterd simulate: {exc}", file=sys.stderr)
            return EXIT_CONFIG
        for r in asyncio.run(run.run()):
            rows.append(r)
            if not args.json:
                print(f"  seed {seed} {'delivered' if r['delivered'] else r['result']:<9} "
                      f"object ({r['object'][0]:6.2f}, {r['object'][1]:6.2f}) -> drop "
                      f"({r['drop'][0]:6.2f}, {r['drop'][1]:6.2f}) {r['seconds']:6.1f} s "
                      f"placed {r.get('drop_error_m', 0):.3f} m off, collisions "
                      f"{r['collisions']} {r['reason']}", flush=True)
    summary = summarise(rows)
    print(json.dumps({"missions": rows, "summary": summary}) if args.json
          else json.dumps(summary))
    return EXIT_OK


def run_dock(args: argparse.Namespace) -> int:
    """``--dock N``: N dockings per world (--world, else apartment and warehouse)."""
    import time

    from daemon.lockstep.dock import DockRun, summarise

    if args.dock < 1:
        print("arbiterd simulate: --dock needs N >= 1", file=sys.stderr)
        return EXIT_USAGE
    started = time.perf_counter()
    rows: list[dict[str, Any]] = []
    for world in [args.world] if args.world else ["apartment", "warehouse"]:
        try:
            run = DockRun(world, args.seed or 1, args.dock)
        except (ConfigError, SimConfigError, WorldError, OSError, ValueError) as exc:
            print(f"arbiterd simulate: {exc}", file=sys.stderr)
            return EXIT_CONFIG
        for r in asyncio.run(run.run()):
            rows.append(r)
            if not args.json:
                print(f"  {world} {'docked' if r['docked'] else r['result']:<8} from "
                      f"{r['distance_m']:5.2f} m {r['seconds']:6.1f} s error "
                      f"{r.get('error_m', 0):.4f} m {r.get('error_deg', 0):.2f} deg "
                      f"collisions {r['collisions']} {r['reason']}", flush=True)
    summary = summarise(rows, time.perf_counter() - started)
    print(json.dumps({"dockings": rows, **summary}) if args.json else json.dumps(summary))
    return EXIT_OK


def run_day(args: argparse.Namespace) -> int:
    """``--day HOURS``: missions on the battery, beside an infinite one."""
    from daemon.lockstep.day import day_run

    if not 0 < args.day <= 48:
        print("arbiterd simulate: --day needs 0 < HOURS <= 48", file=sys.stderr)
        return EXIT_USAGE
    try:
        result = asyncio.run(day_run(args.world or "warehouse", args.seed or 1, args.day))
    except (ConfigError, SimConfigError, WorldError, OSError, ValueError) as exc:
        print(f"arbiterd simulate: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    print(json.dumps(result))
    return EXIT_OK


def _config(args: argparse.Namespace) -> Config:
    config = load_config(Path(args.config) if args.config else None, sim=True, env={})
    overrides = {"seed": args.seed, "world_file": args.world or None,
                 "metrics_csv": args.csv or None}
    config.update("sim", {key: value for key, value in overrides.items() if value is not None})
    return config


def format_report(r: dict[str, Any]) -> str:
    cov, safety, autonomy = r["coverage"], r["safety"], r["autonomy"]
    lines = [
        f"arbiterd simulate: {r['seconds']:g} s of {r['world']} (seed {r['seed']}) in "
        f"{r['wall_s']:.2f} s wall, {r['realtime_factor']}x real time",
        f"  collisions          {r['collisions']}",
        f"  path length         {r['path_length_m']:.2f} m",
        f"  mean speed          {r['mean_speed_m_s']:.3f} m/s (max {r['max_speed_m_s']:.2f})",
        f"  smoothness (RMS)    linear acc {r['smoothness']['rms_linear_acceleration_m_s2']:.3f}"
        f" m/s2, jerk {r['smoothness']['rms_linear_jerk_m_s3']:.1f} m/s3; angular acc "
        f"{r['smoothness']['rms_angular_acceleration_rad_s2']:.3f} rad/s2",
        f"  coverage            {100 * cov['fraction']:.1f} % of the free area "
        f"({cov['visited_cells']}/{cov['free_cells']} cells of {cov['cell_m']} m)",
        f"  nearest approach    {r['min_clearance_m']:.3f} m (footprint to obstacle)",
    ]
    if autonomy["mode"] != "off" or autonomy["transitions"]:
        times = ", ".join(f"{k} {v:.1f} s" for k, v in autonomy["state_times_s"].items() if v)
        lines.append(f"  autonomy            {autonomy['transitions']} transitions; {times}")
    if safety["enabled"]:
        acts = ", ".join(f"{k} {safety['entries'][k]}x / {safety['time_s'][k]:.1f} s"
                         for k in ("stop", "limit", "slowdown"))
        lines.append(f"  collision monitor   {acts}")
    else:
        lines.append("  collision monitor   disabled")
    if "mapping" in r:
        lines += _mapping_lines(r["mapping"])
    for mark in r["marks"]:
        lines.append(f"  at {mark['t']:7.2f} s {mark['label']:<10} x {mark['x']:.2f} y "
                     f"{mark['y']:.2f} v {mark['v']:.2f} clearance {mark['clearance_m']:.3f} m "
                     f"safety {mark['safety']}")
    return "\n".join(lines)


def _mapping_lines(m: dict[str, Any]) -> list[str]:
    pose, odom = m["pose_error"], m["odometry_error"]
    lines = [f"  mapping             {m['revolutions']} revolutions",
             f"    pose error        RMS {pose['rms_m']:.3f} m / {pose['rms_deg']:.2f} deg, max "
             f"{pose['max_m']:.3f} m / {pose['max_deg']:.2f} deg",
             f"    odometry alone    RMS {odom['rms_m']:.3f} m / {odom['rms_deg']:.2f} deg, max "
             f"{odom['max_m']:.3f} m / {odom['max_deg']:.2f} deg"]
    if "map" in m:
        lines.append(f"    map               precision {m['map']['precision']:.3f}, recall "
                     f"{m['map']['recall']:.3f} at one cell ({m['map']['width']} x "
                     f"{m['map']['height']} cells)" +
                     (f" -> {m['map']['file']}" if "file" in m["map"] else ""))
    return lines
