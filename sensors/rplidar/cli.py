# `arbiterd lidar info|health|scan`: talk to an RPLIDAR directly from the command line.
from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from typing import Any

import numpy as np

from sensors.rplidar import requests as p
from sensors.rplidar.assembler import Revolution, RevolutionAssembler
from sensors.rplidar.client import (
    LidarError,
    LidarTimeout,
    PortGone,
    RplidarClient,
    UnknownScanMode,
    describe,
    has_lidar_conf,
    open_serial,
)

EXIT_OK, EXIT_USAGE, EXIT_HARDWARE = 0, 2, 69
REVOLUTION_TIMEOUT_S = 5.0


def add_parser(subparsers: Any) -> None:
    """Add the ``lidar`` subcommand to an argparse subparsers object."""
    lidar = subparsers.add_parser("lidar", help="talk to an RPLIDAR directly",
                                  description="Query or stream an RPLIDAR on a serial port.")
    configure(lidar)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=["info", "health", "scan"],
                        help="info: model and firmware; health: the device's health; "
                        "scan: revolutions")
    parser.add_argument("--port", required=True, help="serial port, e.g. /dev/rplidar")
    parser.add_argument("--baud", type=int, default=115200,
                        help="115200 (A1, A2M8), 256000 (A2M7, A3, S1), 460800 (C1), "
                             "1000000 (S2, S3)")
    parser.add_argument("--mode", default="express",
                        help="scan mode: standard, express or a name the device reports")
    parser.add_argument("--revolutions", type=int, default=1, help="whole turns to print")
    parser.add_argument("--json", action="store_true", help="machine-readable output")


def run(args: argparse.Namespace) -> int:
    """Run one lidar action; exit 0 ok, 2 usage, 69 lidar unavailable."""
    if args.revolutions < 1:
        print("arbiterd lidar: --revolutions must be at least 1", file=sys.stderr)
        return EXIT_USAGE
    try:
        port = open_serial(args.port, args.baud)
    except PortGone as exc:
        print(f"arbiterd lidar: {exc}", file=sys.stderr)
        return EXIT_HARDWARE
    client = RplidarClient(port)
    try:
        return _dispatch(client, args)
    except UnknownScanMode as exc:
        print(f"arbiterd lidar: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except LidarTimeout as exc:
        print(f"arbiterd lidar: no answer from {args.port} at {args.baud} baud ({exc}); "
              "check the port, the baud rate and the lidar's power", file=sys.stderr)
        return EXIT_HARDWARE
    except LidarError as exc:
        print(f"arbiterd lidar: {exc}", file=sys.stderr)
        return EXIT_HARDWARE
    finally:
        _shutdown(client)


def _dispatch(client: RplidarClient, args: argparse.Namespace) -> int:
    client.stop()
    try:
        info = client.info()
    except LidarTimeout:
        client.reset()
        info = client.info()
    if args.action == "info":
        return _info(client, info, args.json)
    if args.action == "health":
        return _health(client.health(), args.json)
    return _scan(client, info, args)


def _info(client: RplidarClient, info: p.DeviceInfo, as_json: bool) -> int:
    out: dict[str, Any] = describe(info) | {"family": info.family}
    if info.firmware_version >= (1, 17):
        rate = client.sample_rate()
        out["sample_time_us"] = {"standard": rate.standard_us, "express": rate.express_us}
    if has_lidar_conf(info):
        modes, typical = client.scan_modes()
        out["scan_modes"] = [{"id": m.id, "name": m.name, "us_per_sample": m.us_per_sample,
                              "max_distance_m": m.max_distance_m,
                              "answer_type": f"0x{m.answer_type:02X}"} for m in modes]
        out["typical_mode"] = typical
    if as_json:
        print(json.dumps(out))
        return EXIT_OK
    print(f"model {out['model']} (0x{info.model:02X}, {info.family}), firmware {info.firmware}, "
          f"hardware {info.hardware}, serial {info.serial}")
    for mode in out.get("scan_modes", []):
        mark = " (typical)" if mode["id"] == out["typical_mode"] else ""
        print(f"  mode {mode['id']} {mode['name']}: {mode['us_per_sample']:g} µs/sample, "
              f"{mode['max_distance_m']:g} m, answer {mode['answer_type']}{mark}")
    return EXIT_OK


def _health(health: p.Health, as_json: bool) -> int:
    if as_json:
        print(json.dumps({"status": health.status_name, "error_code": health.error_code}))
    else:
        print(f"health {health.status_name}, error code 0x{health.error_code:04X}")
    return EXIT_HARDWARE if health.status == 2 else EXIT_OK


def _scan(client: RplidarClient, info: p.DeviceInfo, args: argparse.Namespace) -> int:
    plan = client.plan(args.mode, info)
    client.motor(info, True)
    client.start_scan(plan)
    try:
        return _print_revolutions(client, plan.us_per_sample, plan.name, args)
    finally:
        client.write(p.stop())
        client.motor(info, False)


def _print_revolutions(client: RplidarClient, us_per_sample: float, mode: str,
                       args: argparse.Namespace) -> int:
    assembler = RevolutionAssembler(sample_period=us_per_sample * 1e-6)
    printed = 0
    deadline = time.monotonic() + REVOLUTION_TIMEOUT_S
    while printed < args.revolutions:
        if time.monotonic() > deadline:
            raise LidarTimeout(f"no whole revolution within {REVOLUTION_TIMEOUT_S:.0f} s "
                               f"in mode {mode}")
        events, t_arrival = client.stream()
        for rev in assembler.feed(events, t_arrival):
            if printed < args.revolutions:
                _print_revolution(rev, printed, args.json)
                printed += 1
                deadline = time.monotonic() + REVOLUTION_TIMEOUT_S
    return EXIT_OK


def _print_revolution(rev: Revolution, index: int, as_json: bool) -> None:
    if as_json:
        print(json.dumps(rev.to_cli_json()), flush=True)
        return
    valid = rev.distance_mm > 0
    line = f"revolution {index + 1}: {len(rev)} samples, {int(valid.sum())} returns"
    if rev.scan_time > 0:
        line += f", {1 / rev.scan_time:.1f} Hz"
    if valid.any():
        nearest = int(np.argmin(np.where(valid, rev.distance_mm, np.inf)))
        line += (f", nearest {rev.distance_mm[nearest] / 1000:.3f} m "
                 f"at {rev.angle_deg[nearest]:.1f}°")
    print(line, flush=True)


def _shutdown(client: RplidarClient) -> None:
    with contextlib.suppress(Exception):
        client.port.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="arbiterd lidar",
                                     description="Query or stream an RPLIDAR on a serial port.")
    configure(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
