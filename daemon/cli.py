# The `arbiterd` command line: run, check, status, safe-stop, test-motors, bench, simulate, ...
from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import json
import logging
import math
import os
import sys
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from daemon import __version__
from daemon.app import EXIT_CONFIG, EXIT_HARDWARE, EXIT_OK, EXIT_USAGE, Daemon
from daemon.bench import SUITES, suites_help
from daemon.components.http.settings import HttpSettings
from daemon.components.recorder import cli as record_cli
from daemon.components.recorder.paths import listing_directory
from daemon.components.recorder.settings import RecorderSettings
from daemon.config import Config, ConfigError, ConfigUnreadable, load_config
from daemon.health import problem_of as problem_text
from daemon.logthrottle import RepeatFilter
from daemon.settings import LoggingSettings
from sensors.rplidar import cli as lidar_cli
from sensors.rplidar.settings import LidarSettings

EXIT_BROKEN_PIPE = 141  # what a shell reports for a command killed by SIGPIPE
LEVELS = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING,
          "error": logging.ERROR}
# syslog priorities journald reads from a "<N>" line prefix
SYSLOG_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3,
                   logging.CRITICAL: 2}


class JournalFormatter(logging.Formatter):
    """``<6>arbiterd.control: message`` to the journal (it has its own time stamps),
    ``2026-11-26 14:02:03.125 INFO arbiterd: message`` elsewhere (without the time when
    ``timestamps`` is off)."""

    def __init__(self, journald: bool, timestamps: bool) -> None:
        fmt = "%(asctime)s.%(msecs)03d %(levelname)s " if timestamps and not journald else (
            "" if journald else "%(levelname)s ")
        super().__init__(fmt + "%(name)s: %(message)s", datefmt="%Y-%m-%d %H:%M:%S")
        self.journald = journald

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        if self.journald:
            prefix = f"<{SYSLOG_PRIORITY.get(record.levelno, 6)}>"
            return "\n".join(prefix + line for line in text.splitlines())
        return text


def writes_to_journal(stream: Any, env: Mapping[str, str]) -> bool:
    """``stream`` is systemd's journal: ``$JOURNAL_STREAM`` names its device and inode. The
    variable alone does not count: a terminal of a desktop session inherits it too."""
    try:
        device, inode = (int(part) for part in env.get("JOURNAL_STREAM", "").split(":"))
        found = os.fstat(stream.fileno())
    except (ValueError, OSError, AttributeError):  # io.UnsupportedOperation is an OSError
        return False
    return (found.st_dev, found.st_ino) == (device, inode)


def setup_logging(level: str = "info", timestamps: bool = False, stream: Any = None,
                  env: Mapping[str, str] | None = None) -> None:
    """Log lines to ``stream`` (stderr): for journald when it is the journal, else with the
    level and, with ``timestamps``, the time."""
    stream = sys.stderr if stream is None else stream
    handler = logging.StreamHandler(stream)
    journald = writes_to_journal(stream, os.environ if env is None else env)
    handler.setFormatter(JournalFormatter(journald, timestamps))
    handler.addFilter(RepeatFilter())
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(LEVELS[level])
    logging.getLogger("aiohttp.access").setLevel(logging.WARNING)


DEFAULT_URL = "http://127.0.0.1:8085"
STATUS_TIMEOUT_S = 5.0


def _load(args: argparse.Namespace) -> Config:
    """The config a command reads; ``run`` and ``check`` without a config file: the whole
    simulated robot (daemon/config.py WHOLE_ROBOT)."""
    path = Path(args.config) if getattr(args, "config", None) else None
    return load_config(path, sim=getattr(args, "sim", False),
                       whole_robot=getattr(args, "command", "") in ("run", "check"))


def _report_config_error(exc: ConfigError, args: argparse.Namespace, out: Any = None,
                         lead: str = "arbiterd") -> int:
    out = out or sys.stderr
    count = len(exc.problems)
    print(f"{lead}: configuration error ({count} problem{'s' if count != 1 else ''}):",
          file=out)
    for problem in exc.problems:
        print(f"  {problem}", file=out)
    if isinstance(exc, ConfigUnreadable):
        print(f"  {_unreadable_hint(args, exc)}", file=out)
    return EXIT_CONFIG


def _unreadable_hint(args: argparse.Namespace, exc: ConfigUnreadable) -> str:
    """What to run instead when the installed service's config is not readable by this user."""
    config = f" --config {exc.path}" if getattr(args, "config", None) else ""
    if args.command == "run":
        return ("the installed service runs with it (sudo systemctl restart arbiterd); "
                "`arbiterd run --sim` runs the simulated robot on the built-in defaults, "
                "or pass --config FILE with a config of your own")
    return f"run it as root: sudo arbiterd {args.command}{config}"


def cmd_run(args: argparse.Namespace) -> int:
    try:
        config = _load(args)
    except ConfigError as exc:
        setup_logging()
        return _report_config_error(exc, args)
    if args.http_port is not None:
        config.update("http", {"port": args.http_port})
    if args.ws_port is not None:
        config.update("rosbridge", {"port": args.ws_port})
    logging_settings = config.get(LoggingSettings)
    setup_logging(logging_settings.level, logging_settings.timestamps)
    return asyncio.run(Daemon(config).run())


def tcp_port(text: str) -> int:
    """An ``--http-port``/``--ws-port`` value: a TCP port number, 1 to 65535."""
    try:
        port = int(text)
    except ValueError:
        port = 0
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a TCP port: give a number from 1 "
                                         "to 65535")
    return port


def cmd_check(args: argparse.Namespace) -> int:
    """The verdict on the first line; then the problems; then the details (probe findings,
    warnings, and with --verbose the effective configuration). Everything on stdout."""
    try:
        config = _load(args)
    except ConfigError as exc:
        return _report_config_error(exc, args, sys.stdout, "arbiterd check: FAILED")
    if args.no_probe:
        print(f"arbiterd check: ok: {config.source}: configuration valid "
              "(hardware not probed: --no-probe)")
        _check_details(config, args, "")
        return EXIT_OK
    from daemon.probe import probe_hardware

    details = io.StringIO()
    try:
        with contextlib.redirect_stderr(details):  # the probes' findings follow the verdict
            problems = asyncio.run(probe_hardware(config))
    except ConfigError as exc:
        return _report_config_error(exc, args, sys.stdout, "arbiterd check: FAILED")
    if problems:
        count = len(problems)
        print(f"arbiterd check: FAILED: {config.source}: configuration valid, but {count} "
              f"hardware problem{'s' if count != 1 else ''}:")
        for problem in problems:
            print(f"  hardware: {problem}")
    else:
        print(f"arbiterd check: ok: {config.source}: configuration valid and the hardware "
              f"answers ({_probed(config)})")
    _check_details(config, args, details.getvalue())
    return EXIT_HARDWARE if problems else EXIT_OK


def _probed(config: Config) -> str:
    what = f"driver {config['driver']['type']}"
    if config.get(LidarSettings).enabled:
        what += f", lidar on {config['lidar']['port']}"
    if config["arm"]["enabled"]:
        what += f", arm servos ({config['arm']['backend']})"
    if config["battery"]["enabled"] and config["battery"]["device"] != "sim":
        what += f", battery monitor ({config['battery']['device']})"
    return what


def _check_details(config: Config, args: argparse.Namespace, probe_output: str) -> None:
    for warning in config.warnings:
        print(f"warning: {warning}")
    if probe_output:
        print(probe_output, end="" if probe_output.endswith("\n") else "\n")
    if args.verbose:
        print(f"# effective configuration ({config.source})")
        print(render_toml(config.as_dict()))
    else:
        print("(arbiterd check --verbose also prints the effective configuration)")


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


def _daemon_address(args: argparse.Namespace, command: str) -> tuple[str, str] | int:
    """The running daemon's base URL and token (``_status_url``), or the exit code after
    saying why there is none."""
    try:
        return _status_url(args)
    except ConfigError as exc:
        return _report_config_error(exc, args)
    except ValueError as exc:
        print(f"arbiterd {command}: {exc}", file=sys.stderr)
        return EXIT_USAGE


def cmd_status(args: argparse.Namespace) -> int:
    address = _daemon_address(args, "status")
    if isinstance(address, int):
        return address
    base, token = address
    try:
        health = _get_json(f"{base}/api/health", token)
        latency = _get_json(f"{base}/api/latency", token)
    except (urllib.error.URLError, OSError, ValueError) as exc:
        print(f"arbiterd status: {unreachable(base, exc)}", file=sys.stderr)
        return EXIT_HARDWARE
    print(format_status(health, latency, base))
    return EXIT_OK if health.get("status") != "error" else 1


def unreachable(base: str, exc: BaseException) -> str:
    """Why nothing answered at ``base``, and what to do."""
    reason = getattr(exc, "reason", exc)
    if isinstance(reason, ConnectionRefusedError):
        return (f"no daemon answers at {base} (connection refused): arbiterd is not running "
                "there. Start it: `arbiterd run --sim` (the simulated robot) or `sudo "
                "systemctl start robot.target` (the service); if it runs elsewhere, pass "
                "--url HOST:PORT or --config FILE")
    if isinstance(reason, TimeoutError):
        return f"no answer from {base} within {STATUS_TIMEOUT_S:g} s: is it the daemon's address?"
    return f"cannot reach {base}: {reason}"


def status_base_url(text: str) -> str:
    """``--url``: ``http://host:port``, ``host:port``, ``host`` or a port, as a base URL."""
    url = text.strip()
    if url.isdigit():
        url = f"127.0.0.1:{url}"
    if "://" not in url:
        url = f"http://{url}"
    url = url.rstrip("/")
    parsed = urllib.parse.urlsplit(url)
    try:
        parsed.port  # noqa: B018 (a port that is no number raises)
    except ValueError:
        parsed = parsed._replace(netloc="")
    if parsed.scheme not in ("http", "https") or not parsed.hostname:
        raise ValueError(f"--url {text}: not the daemon's address; give HOST:PORT or "
                         "http://HOST:PORT, e.g. --url 127.0.0.1:8085")
    return url


def _status_url(args: argparse.Namespace) -> tuple[str, str]:
    """--url, else the [http] address of --config or the default config (env overrides too);
    and the config's token, for a daemon whose reads need it."""
    if args.url:
        return status_base_url(args.url), ""
    try:
        config = _load(args)
    except ConfigUnreadable as exc:
        if args.config:
            raise
        print(f"arbiterd status: {exc.problems[0]}; asking {DEFAULT_URL} "
              "(sudo arbiterd status reads the configured port)", file=sys.stderr)
        return DEFAULT_URL, ""
    http = config.get(HttpSettings)
    host, port = http.host, http.port
    if host in ("", "0.0.0.0", "::", "[::]"):
        host = "127.0.0.1"
    elif ":" in host and not host.startswith("["):
        host = f"[{host}]"
    return f"http://{host}:{port}", config.token


def _get_json(url: str, token: str = "") -> dict[str, Any]:
    request = urllib.request.Request(url)
    if token:
        request.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(request, timeout=STATUS_TIMEOUT_S) as response:
            data: dict[str, Any] = json.load(response)
    except urllib.error.HTTPError as exc:  # 503 still carries the health body
        data = json.load(exc)
    return data


def format_status(health: dict[str, Any], latency: dict[str, Any], base: str = "") -> str:
    """The health summary: one line for the daemon, one aligned row per component (with why,
    when it is not ok), then the latency figures."""
    at = f" at {base}" if base else ""
    lines = [f"arbiterd {health.get('version')}{at}: {health.get('status')} "
             f"({health.get('state')}), {health.get('mode')} mode, driver "
             f"{health.get('driver')}, up {_duration(health.get('uptime_s') or 0)}"]
    rows = [(name, str(comp.get("status")), _why(comp))
            for name, comp in health.get("components", {}).items()]
    execs = latency.get("receipt_to_exec_ms", {})
    tick = latency.get("tick", {})
    lateness = tick.get("lateness_ms", {})
    rows += [("commands", str(latency.get("commands", 0)), ""),
             ("receipt->exec", _percentiles(execs), ""),
             ("tick lateness", _percentiles(lateness),
              f"{tick.get('late', 0)} late, {tick.get('missed', 0)} missed of "
              f"{tick.get('count', 0)} ticks" if tick else "")]
    width = max(len(row[0]) for row in rows)
    status_width = max(len(row[1]) for row in rows[:-3]) if len(rows) > 3 else 0
    for i, (name, value, detail) in enumerate(rows):
        column = status_width if i < len(rows) - 3 else 0
        text = f"  {name:<{width}}  {value:<{column}}" + (f"  {detail}" if detail else "")
        lines.append(text.rstrip())
    return "\n".join(lines)


def _why(component: dict[str, Any]) -> str:
    """Why a component is not ok (its problem text, else its state), or what it says when it
    is ok and has a problem text."""
    text = problem_text(component)
    if not text and component.get("status") != "ok":
        text = str(component.get("last_error") or component.get("reason")
                   or component.get("state") or "")
    return text


def _percentiles(figures: dict[str, Any]) -> str:
    if not figures.get("count"):
        return "-"
    return f"p50 {_ms(figures.get('p50'))}  p99 {_ms(figures.get('p99'))}"


def _ms(value: Any) -> str:
    """A duration in ms to about three significant digits (16.4, 3.17, 0.012, 322)."""
    if not isinstance(value, int | float):
        return "-"
    digits = 2 - math.floor(math.log10(abs(value))) if value else 0
    return f"{value:.{min(max(digits, 0), 3)}f} ms"


def _duration(seconds: float) -> str:
    whole = int(seconds)
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    if hours:
        return f"{hours} h {minutes:02d} min"
    return f"{minutes} min {secs:02d} s" if minutes else f"{secs} s"


def cmd_safe_stop(args: argparse.Namespace) -> int:
    setup_logging()
    if args.sim:  # the unit passes its ARBITERD_ARGS: the simulated motors died with the daemon
        print("arbiterd safe-stop: simulated robot (--sim): no hardware to zero")
        return EXIT_OK
    try:
        config = _load(args)
    except ConfigError as exc:
        return _report_config_error(exc, args)
    from daemon.probe import safe_stop

    try:
        asyncio.run(safe_stop(config))
    except ConfigError as exc:
        return _report_config_error(exc, args)
    except Exception as exc:
        print(f"arbiterd safe-stop: could not zero the motors: {exc}", file=sys.stderr)
        return EXIT_HARDWARE
    arm = f"; arm servos: {config['arm']['on_stop']}" if config["arm"]["enabled"] else ""
    print(f"arbiterd safe-stop: motors zeroed through the {config['driver']['type']} "
          f"driver{arm}")
    return EXIT_OK


def cmd_test_motors(args: argparse.Namespace) -> int:
    setup_logging("warning")
    from daemon.bringup.cli import test_motors

    try:
        return test_motors(_load(args), args)
    except ConfigError as exc:
        return _report_config_error(exc, args)


def cmd_bench(args: argparse.Namespace) -> int:
    from daemon.bench.runner import run_suites

    return run_suites(args.only, quick=args.quick, as_json=args.json)


def cmd_simulate(args: argparse.Namespace) -> int:
    from daemon.lockstep import command

    setup_logging("warning")
    return command.run(args)


def cmd_fleet(args: argparse.Namespace) -> int:
    import asyncio

    from daemon.components.fleet.component import available
    from daemon.components.fleet.operator import serve

    setup_logging(args.log_level)
    missing = available()
    if missing is not None:
        print(f"arbiterd fleet: {missing}", file=sys.stderr)
        return 2
    try:
        config = load_config(args.config, sim=True)
    except ConfigError as exc:
        return _report_config_error(exc, args)
    return asyncio.run(serve(config, args.listen, args.http_port))


def _add_fleet(sub: Any) -> None:
    fleet = sub.add_parser("fleet", help="the operator's side: a Zenoh router and the fleet "
                           "page (docs/fleet.md)")
    fleet.add_argument("--listen", metavar="tcp/HOST:PORT",
                       help="the router's endpoint (default [fleet] operator.listen, "
                       "tcp/0.0.0.0:7447)")
    fleet.add_argument("--http-port", type=tcp_port, metavar="PORT",
                       help="the fleet page's port (default 8086)")
    fleet.add_argument("--config", type=Path, metavar="PATH",
                       help="a config file: its [fleet] operator.* keys and [security]")
    fleet.add_argument("--log-level", default="info",
                       choices=["debug", "info", "warning", "error"])
    fleet.set_defaults(func=cmd_fleet)


def cmd_lidar(args: argparse.Namespace) -> int:
    result: int = lidar_cli.run(args)
    return result


def cmd_record(args: argparse.Namespace) -> int:
    directory = Path(args.dir) if getattr(args, "dir", None) else None
    if directory is None and record_cli.needs_directory(args):
        try:
            config = _load(args)
        except ConfigError as exc:
            return _report_config_error(exc, args)
        directory = listing_directory({"directory": config.get(RecorderSettings).directory})
    return record_cli.run(args, directory or Path("."))


def cmd_map(args: argparse.Namespace) -> int:
    from daemon.components.mapping import cli as map_cli
    from daemon.components.mapping.settings import MappingSettings
    from daemon.paths import listing_directory as state_listing

    if args.map_command == "save":
        address = _daemon_address(args, "map save")
        return address if isinstance(address, int) else map_cli.run_save(args.name, *address)
    try:
        config = _load(args)
    except ConfigError as exc:
        return _report_config_error(exc, args)
    settings = config.get(MappingSettings)
    directory = Path(args.dir) if args.dir else state_listing(settings.directory, "maps")
    if args.map_command == "list":
        return map_cli.run_list(directory, args.json)
    return map_cli.run_build(args, settings, directory)


def cmd_mission(args: argparse.Namespace) -> int:
    from daemon.components.navigation import cli as mission_cli

    address = _daemon_address(args, "mission")
    if isinstance(address, int):
        return address
    base, token = address
    if args.url and args.config:  # the address given, the token from the config
        try:
            token = _load(args).token
        except ConfigError as exc:
            return _report_config_error(exc, args)
    return mission_cli.run_mission(args.file, base, token, wait=not args.no_wait)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="arbiterd", description="ArbiterROS on-robot daemon")
    parser.add_argument("--version", action="version", version=f"arbiterd {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run the daemon")
    run.add_argument("--config", help="config file (default /etc/arbiterd/arbiterd.toml "
                     "if present, else built-in defaults on the simulated robot)")
    run.add_argument("--sim", action="store_true", help="force the simulated hardware")
    run.add_argument("--http-port", type=tcp_port, metavar="PORT",
                     help="serve HTTP (API and console) on PORT instead of [http] port; with "
                     "--ws-port, a second daemon runs beside another")
    run.add_argument("--ws-port", type=tcp_port, metavar="PORT",
                     help="serve rosbridge on PORT instead of [rosbridge] port")
    run.set_defaults(func=cmd_run)
    check = sub.add_parser("check", help="validate the config and probe the hardware; the "
                           "verdict comes first")
    check.add_argument("--config", help="config file (default /etc/arbiterd/arbiterd.toml; "
                       "the installed one is readable by root: sudo arbiterd check)")
    check.add_argument("--no-probe", action="store_true", help="validate only")
    check.add_argument("-v", "--verbose", action="store_true",
                       help="also print the effective configuration")
    check.set_defaults(func=cmd_check, sim=False)
    status = sub.add_parser("status", help="summary of a running daemon")
    status.add_argument("--url", help="the daemon's address: HOST:PORT or http://HOST:PORT "
                        f"(default: the [http] address of the config, else {DEFAULT_URL})")
    status.add_argument("--config", help="config file to read the [http] address from "
                        "(default /etc/arbiterd/arbiterd.toml)")
    status.set_defaults(func=cmd_status, sim=False)
    safe = sub.add_parser("safe-stop", help="zero the motors through the configured driver")
    safe.add_argument("--config")
    safe.add_argument("--sim", action="store_true",
                      help="the simulated robot ran: nothing to zero (the unit passes it)")
    safe.set_defaults(func=cmd_safe_stop)
    motors = sub.add_parser("test-motors", help="bring-up: spin each wheel, read the encoders, "
                            "say what is miswired and the config lines that fix it")
    motors.add_argument("--config")
    motors.add_argument("--sim", action="store_true",
                        help="the simulated hardware of [sim] driver (with [sim] miswire)")
    motors.add_argument("--yes", action="store_true",
                        help="the wheels are off the ground: do not ask")
    motors.add_argument("--json", action="store_true", help="print one JSON object")
    motors.set_defaults(func=cmd_test_motors)
    bench = sub.add_parser("bench", help="run the benchmark suites",
                           description="Run the benchmark suites on this machine and print "
                           "each figure with its target,\nthen what missed its target.",
                           epilog=suites_help(),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    bench.add_argument("--json", action="store_true", help="one JSON object per figure")
    bench.add_argument("--quick", action="store_true", help="shorter runs (rougher figures)")
    bench.add_argument("--only", action="append", metavar="SUITE", choices=list(SUITES),
                       help="run only this suite (repeatable; the suites are listed below)")
    bench.set_defaults(func=cmd_bench)
    _add_simulate(sub)
    _add_lidar(sub)
    record_cli.add_parser(sub).set_defaults(func=cmd_record)
    _add_map(sub)
    _add_mission(sub)
    _add_fleet(sub)
    return parser


def _add_mission(sub: Any) -> None:
    from daemon.components.navigation import cli as mission_cli

    mission_cli.add_parser(sub).set_defaults(func=cmd_mission, sim=False)


def _add_map(sub: Any) -> None:
    from daemon.components.mapping import cli as map_cli

    map_cli.add_parser(sub).set_defaults(func=cmd_map)


def _add_simulate(sub: Any) -> None:
    from daemon.lockstep.command import add_parser

    add_parser(sub).set_defaults(func=cmd_simulate)


def _add_lidar(sub: Any) -> None:
    lidar_cli.add_parser(sub)
    sub.choices["lidar"].set_defaults(func=cmd_lidar)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return EXIT_USAGE if exc.code else EXIT_OK
    try:
        code: int = args.func(args)
        sys.stdout.flush()
    except BrokenPipeError:  # `arbiterd status | head`: the reader left; stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    return code


if __name__ == "__main__":
    sys.exit(main())
