# The `arbiterd` command line: run, check, status, safe-stop, bench, lidar.
from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import sys
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

from daemon import __version__
from daemon.app import EXIT_CONFIG, EXIT_HARDWARE, EXIT_OK, EXIT_USAGE, Daemon
from daemon.config import Config, ConfigError, load_config
from sensors.rplidar import cli as lidar_cli

LEVELS = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING,
          "error": logging.ERROR}
# syslog priorities journald reads from a "<N>" line prefix
SYSLOG_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3,
                   logging.CRITICAL: 2}


class JournalFormatter(logging.Formatter):
    """``<6>arbiterd.control: message`` under systemd, ``INFO arbiterd: message`` on a tty."""

    def __init__(self, journald: bool, timestamps: bool) -> None:
        fmt = "%(asctime)s " if timestamps else ""
        super().__init__(fmt + "%(name)s: %(message)s")
        self.journald = journald

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        if self.journald:
            prefix = f"<{SYSLOG_PRIORITY.get(record.levelno, 6)}>"
            return "\n".join(prefix + line for line in text.splitlines())
        return f"{record.levelname} {text}"


def setup_logging(level: str = "info", timestamps: bool = False) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JournalFormatter("JOURNAL_STREAM" in os.environ, timestamps))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(LEVELS[level])
    logging.getLogger("aiohttp.access").setLevel(logging.WARNING)


def _load(args: argparse.Namespace) -> Config:
    path = Path(args.config) if getattr(args, "config", None) else None
    return load_config(path, sim=getattr(args, "sim", False))


def _report_config_error(exc: ConfigError) -> int:
    print(f"arbiterd: configuration error ({len(exc.problems)} problem"
          f"{'s' if len(exc.problems) != 1 else ''}):", file=sys.stderr)
    for problem in exc.problems:
        print(f"  {problem}", file=sys.stderr)
    return EXIT_CONFIG


def cmd_run(args: argparse.Namespace) -> int:
    try:
        config = _load(args)
    except ConfigError as exc:
        setup_logging()
        return _report_config_error(exc)
    setup_logging(config["logging"]["level"], config["logging"]["timestamps"])
    return asyncio.run(Daemon(config).run())


def cmd_check(args: argparse.Namespace) -> int:
    try:
        config = _load(args)
    except ConfigError as exc:
        return _report_config_error(exc)
    print(f"# effective configuration ({config.source})")
    print(render_toml(config.as_dict()))
    for warning in config.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    if args.no_probe:
        return EXIT_OK
    from daemon.probe import probe_hardware

    try:
        problems = asyncio.run(probe_hardware(config))
    except ConfigError as exc:
        return _report_config_error(exc)
    for problem in problems:
        print(f"hardware: {problem}", file=sys.stderr)
    if problems:
        return EXIT_HARDWARE
    print("# hardware probe: ok", file=sys.stderr)
    return EXIT_OK


def render_toml(sections: dict[str, dict[str, Any]]) -> str:
    """A readable TOML rendering of the effective config."""
    out = []
    for section, values in sections.items():
        out.append(f"[{section}]")
        for key, value in values.items():
            out.append(f"{key} = {_toml_value(value)}")
        out.append("")
    return "\n".join(out)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def cmd_status(args: argparse.Namespace) -> int:
    base = args.url.rstrip("/")
    try:
        health = _get_json(f"{base}/api/health")
        latency = _get_json(f"{base}/api/latency")
    except (urllib.error.URLError, OSError, ValueError) as exc:
        print(f"arbiterd status: cannot reach {base}: {exc}", file=sys.stderr)
        return EXIT_HARDWARE
    print(format_status(health, latency))
    return EXIT_OK if health.get("status") != "error" else 1


def _get_json(url: str) -> dict[str, Any]:
    try:
        with urllib.request.urlopen(url, timeout=5) as response:
            data: dict[str, Any] = json.load(response)
    except urllib.error.HTTPError as exc:  # 503 still carries the health body
        data = json.load(exc)
    return data


def format_status(health: dict[str, Any], latency: dict[str, Any]) -> str:
    lines = [f"arbiterd {health.get('version')}: {health.get('status')} "
             f"({health.get('state')}), {health.get('mode')} mode, driver "
             f"{health.get('driver')}, up {health.get('uptime_s', 0):.0f} s"]
    for name, comp in health.get("components", {}).items():
        detail = comp.get("fault") or comp.get("error") or ""
        lines.append(f"  {name:<10} {comp.get('status')}" + (f"  {detail}" if detail else ""))
    execs = latency.get("receipt_to_exec_ms", {})
    tick = latency.get("tick", {}).get("lateness_ms", {})
    lines.append(f"  commands {latency.get('commands', 0)}; receipt->exec ms p50 "
                 f"{execs.get('p50', '-')} p99 {execs.get('p99', '-')}; tick lateness ms p99 "
                 f"{tick.get('p99', '-')}")
    return "\n".join(lines)


def cmd_safe_stop(args: argparse.Namespace) -> int:
    setup_logging()
    try:
        config = _load(args)
    except ConfigError as exc:
        return _report_config_error(exc)
    from daemon.probe import safe_stop

    try:
        asyncio.run(safe_stop(config))
    except ConfigError as exc:
        return _report_config_error(exc)
    except Exception as exc:
        print(f"arbiterd safe-stop: could not zero the motors: {exc}", file=sys.stderr)
        return EXIT_HARDWARE
    print(f"arbiterd safe-stop: motors zeroed through the {config['driver']['type']} driver")
    return EXIT_OK


def cmd_bench(args: argparse.Namespace) -> int:
    from daemon.bench.runner import run_suites

    return run_suites(args.only, quick=args.quick, as_json=args.json)


def cmd_lidar(args: argparse.Namespace) -> int:
    result: int = lidar_cli.run(args)
    return result


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="arbiterd", description="ArbiterROS on-robot daemon")
    parser.add_argument("--version", action="version", version=f"arbiterd {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run the daemon")
    run.add_argument("--config", help="config file (default /etc/arbiterd/arbiterd.toml "
                     "if present, else built-in defaults on the simulated robot)")
    run.add_argument("--sim", action="store_true", help="force the simulated hardware")
    run.set_defaults(func=cmd_run)
    check = sub.add_parser("check", help="validate the config and probe the hardware")
    check.add_argument("--config")
    check.add_argument("--no-probe", action="store_true", help="validate only")
    check.set_defaults(func=cmd_check, sim=False)
    status = sub.add_parser("status", help="summary of a running daemon")
    status.add_argument("--url", default="http://127.0.0.1:8085")
    status.set_defaults(func=cmd_status)
    safe = sub.add_parser("safe-stop", help="zero the motors through the configured driver")
    safe.add_argument("--config")
    safe.set_defaults(func=cmd_safe_stop, sim=False)
    bench = sub.add_parser("bench", help="run the benchmark suite")
    bench.add_argument("--json", action="store_true", help="one JSON object per figure")
    bench.add_argument("--quick", action="store_true", help="shorter runs")
    bench.add_argument("--only", action="append", help="run only this suite (repeatable)")
    bench.set_defaults(func=cmd_bench)
    _add_lidar(sub)
    return parser


def _add_lidar(sub: Any) -> None:
    lidar_cli.add_parser(sub)
    sub.choices["lidar"].set_defaults(func=cmd_lidar)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return EXIT_USAGE if exc.code else EXIT_OK
    code: int = args.func(args)
    return code


if __name__ == "__main__":
    sys.exit(main())
