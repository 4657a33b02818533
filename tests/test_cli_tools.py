# The arbiterd command line as a user meets it: check (verdict first), status (the configured
# address, a closed pipe), safe-stop --sim, and the errors for an unreadable config or a bad
# ARBITERD_* override.
from __future__ import annotations

import argparse
import grp
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from daemon import __version__
from daemon.app import EXIT_CONFIG, EXIT_HARDWARE, EXIT_OK, EXIT_USAGE
from daemon.cli import build_parser, format_status
from daemon.listen import EXIT_PORT_IN_USE
from sim.rplidar_emulator import RplidarEmulator
from tests.support.daemon_subprocess import StartDaemonSubprocess
from tests.support.net import free_port, http
from tests.support.paths import REPO
from tests.support.wait import wait_for

NOBODY = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]


def run_cli(*args: str, env: dict[str, str] | None = None,
            prefix: tuple[str, ...] = ()) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*prefix, sys.executable, "-m", "daemon.cli", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=60,
                          env={**os.environ, **(env or {})})


def lidar_config(tmp_path: Path, port: Path) -> Path:
    path = tmp_path / "arbiterd.toml"
    path.write_text(f'[driver]\ntype = "mock"\n[lidar]\nenabled = true\nport = "{port}"\n')
    return path


def test_check_probes_the_lidar_and_says_its_verdict_first(tmp_path: Path) -> None:
    with RplidarEmulator(tmp_path / "rplidar").start() as lidar:
        config = lidar_config(tmp_path, lidar.link)
        result = run_cli("check", "--config", str(config))
        assert result.returncode == 0, result.stdout + result.stderr
        lines = result.stdout.splitlines()
        assert lines[0] == (f"arbiterd check: ok: {config}: configuration valid and the hardware "
                            f"answers (driver mock, lidar on {lidar.link})")
        assert "# lidar: A1M8" in result.stdout and "health ok" in result.stdout
        assert "[http]" not in result.stdout and len(lines) < 10, "the config only with -v"
        lidar.set_health(2, 0x8001, clears_on_reset=False)
        result = run_cli("check", "--config", str(config))
        assert result.returncode == 69
        first, second = result.stdout.splitlines()[:2]
        assert first == (f"arbiterd check: FAILED: {config}: configuration valid, but 1 hardware "
                         "problem:")
        assert "reports a health error (code 0x8001)" in second


def test_check_verbose_adds_the_effective_configuration(tmp_path: Path) -> None:
    config = tmp_path / "arbiterd.toml"
    config.write_text('[driver]\ntype = "mock"\n[http]\nport = 8123\n')
    result = run_cli("check", "--verbose", "--no-probe", "--config", str(config))
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].startswith(f"arbiterd check: ok: {config}: configuration valid")
    assert f"# effective configuration ({config})" in lines and "port = 8123" in lines


def test_check_reports_a_missing_lidar(tmp_path: Path) -> None:
    result = run_cli("check", "--config", str(lidar_config(tmp_path, tmp_path / "nothing")))
    assert result.returncode == 69
    assert result.stdout.startswith("arbiterd check: FAILED:")
    assert f"hardware: [lidar] {tmp_path / 'nothing'}" in result.stdout


def test_a_bad_override_names_the_variable_not_the_file(tmp_path: Path) -> None:
    config = tmp_path / "arbiterd.toml"
    config.write_text('[driver]\ntype = "mock"\n')
    result = run_cli("check", "--no-probe", "--config", str(config),
                     env={"ARBITERD_HTTP_PORT": "80a", "ARBITERD_HTTP_PROT": "81"})
    assert result.returncode == 78
    assert result.stdout.splitlines()[0] == ("arbiterd check: FAILED: configuration error "
                                             "(2 problems):")
    assert ("environment variable ARBITERD_HTTP_PORT=80a: [http] port: expected an integer"
            in result.stdout)
    assert ("environment variable ARBITERD_HTTP_PROT: no such config key (did you mean "
            "ARBITERD_HTTP_PORT?)" in result.stdout)
    assert str(config) not in result.stdout


# -- the installed service's config, unreadable for a normal user ------------------------------

@pytest.fixture
def etc() -> Iterator[Path]:
    """A directory everyone can reach, as everyone reaches /etc (pytest's tmp_path is 0700)."""
    top = Path(tempfile.mkdtemp(prefix="arbiterd-etc-"))
    top.chmod(0o755)
    yield top
    shutil.rmtree(top)


def service_config(etc: Path, text: str) -> Path:
    """A config laid out as install.sh does (root:dialout here, 0640 in a 0750 directory)."""
    config_dir = etc / "arbiterd"
    config_dir.mkdir()
    path = config_dir / "arbiterd.toml"
    path.write_text(text)
    path.chmod(0o640)
    config_dir.chmod(0o750)
    if os.geteuid() == 0:
        os.chown(config_dir, 0, grp.getgrnam("dialout").gr_gid)  # a group nobody is not in
        os.chown(path, 0, grp.getgrnam("dialout").gr_gid)
    return path


def as_normal_user(default: Path, *args: str,
                   env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """``arbiterd ARGS`` as a user who may not read ``default``, the default config path."""
    code = (f"import sys; from pathlib import Path; import daemon.config as c; "
            f"c.DEFAULT_PATH = Path({str(default)!r}); from daemon.cli import main; "
            f"sys.exit(main({list(args)!r}))")
    prefix = NOBODY if os.geteuid() == 0 else []
    return subprocess.run([*prefix, sys.executable, "-c", code], cwd=REPO, capture_output=True,
                          text=True, timeout=60, env={**os.environ, **(env or {})})


def test_check_without_config_says_to_use_sudo(etc: Path) -> None:
    default = service_config(etc, '[driver]\ntype = "mock"\n')
    result = as_normal_user(default, "check")
    assert result.returncode == 78, result.stderr
    assert result.stdout.splitlines() == [
        "arbiterd check: FAILED: configuration error (1 problem):",
        f"  {default}: cannot read it: permission denied (only root and the group 'dialout' "
        "may read it)",
        "  run it as root: sudo arbiterd check"]
    assert "Traceback" not in result.stderr


def test_run_without_config_says_what_to_do_instead(etc: Path) -> None:
    default = service_config(etc, '[driver]\ntype = "mock"\n')
    result = as_normal_user(default, "run")
    assert result.returncode == 78
    assert f"{default}: cannot read it: permission denied" in result.stderr
    assert "`arbiterd run --sim` runs the simulated robot on the built-in defaults" in result.stderr
    assert "Traceback" not in result.stderr


def test_status_without_config_says_which_address_it_asks(etc: Path) -> None:
    default = service_config(etc, '[driver]\ntype = "mock"\n[http]\nport = 8123\n')
    result = as_normal_user(default, "status")
    assert (f"arbiterd status: {default}: cannot read it: permission denied (only root and the "
            "group 'dialout' may read it); asking http://127.0.0.1:8085 (sudo arbiterd status "
            "reads the configured port)") in result.stderr
    assert "Traceback" not in result.stderr


def test_run_sim_without_config_falls_back_to_the_defaults_and_says_why(
        tmp_path: Path, etc: Path) -> None:
    default = service_config(etc, '[driver]\ntype = "mock"\n')
    port = free_port()
    env = {"ARBITERD_HTTP_HOST": "127.0.0.1", "ARBITERD_HTTP_PORT": str(port),
           "ARBITERD_ROSBRIDGE_HOST": "127.0.0.1", "ARBITERD_ROSBRIDGE_PORT": str(free_port())}
    code = (f"import sys; from pathlib import Path; import daemon.config as c; "
            f"c.DEFAULT_PATH = Path({str(default)!r}); from daemon.cli import main; "
            f"sys.exit(main(['run', '--sim']))")
    log = tmp_path / "daemon.log"
    with log.open("w") as out:
        proc = subprocess.Popen([*(NOBODY if os.geteuid() == 0 else []), sys.executable, "-c",
                                 code], cwd=REPO, stdout=out, stderr=subprocess.STDOUT,
                                env={**os.environ, **env})
    try:
        body = wait_for(lambda: _health(port, proc, log), "the daemon's /api/health")
        assert body["mode"] == "sim"
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(15) == 0
    text = log.read_text()
    assert (f"{default} is the installed service's config and this user may not read it "
            "(only root and the group 'dialout' may read it): running the simulated robot on "
            "the built-in defaults; pass --config FILE") in text


def _health(port: int, proc: subprocess.Popen[bytes], log: Path) -> object:
    assert proc.poll() is None, log.read_text()
    try:
        status, body = http("GET", f"http://127.0.0.1:{port}/api/health", timeout=1.0)
    except OSError:
        return None
    return body if status in (200, 503) else None


# -- status ------------------------------------------------------------------------------------

def test_status_reads_the_address_from_the_config(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    daemon = daemon_subprocess()
    daemon.post("/api/cmd_vel", {"linear": {"x": 0.1}})
    result = run_cli("status", "--config", str(daemon.config_path))
    assert result.returncode == 0, result.stderr
    first = result.stdout.splitlines()[0]
    assert first.startswith(f"arbiterd {__version__} at {daemon.base_url}: ok (ready), "
                            "hardware mode, driver mock, up ")
    assert "\n  control " in result.stdout and "\n  commands       1\n" in result.stdout
    by_env = run_cli("status", "--config", os.devnull,
                     env={"ARBITERD_HTTP_PORT": str(daemon.http_port)})
    assert by_env.returncode == 0, by_env.stderr
    assert ": ok (ready), hardware mode, driver mock" in by_env.stdout.splitlines()[0]
    by_url = run_cli("status", "--url", daemon.base_url)
    assert by_url.returncode == 0
    assert by_url.stdout.split(", up ")[0] == first.split(", up ")[0]
    for without_scheme in (f"127.0.0.1:{daemon.http_port}", str(daemon.http_port)):
        short = run_cli("status", "--url", without_scheme)
        assert short.returncode == 0, short.stderr
        assert short.stdout.split(", up ")[0] == first.split(", up ")[0]


def test_status_sends_the_config_token_when_reads_need_it(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    daemon = daemon_subprocess('[security]\ntoken = "s3cret-t0ken"\nread_requires_token = true\n'
                            'open_health = true\n')
    assert daemon.get("/api/latency")[0] == 401
    daemon.post("/api/cmd_vel", {"linear": {"x": 0.1}}, token="s3cret-t0ken")
    result = run_cli("status", "--config", str(daemon.config_path))
    assert result.returncode == 0, result.stderr
    assert ": ok (ready), hardware mode, driver mock" in result.stdout.splitlines()[0]
    assert "\n  commands       1\n" in result.stdout  # /api/latency answered: the token was sent


def test_status_into_a_closed_pipe_is_quiet(
        daemon_subprocess: StartDaemonSubprocess) -> None:
    daemon = daemon_subprocess()
    read_end, write_end = os.pipe()
    os.close(read_end)  # `arbiterd status | head -1` with head already gone
    try:
        result = subprocess.run([sys.executable, "-m", "daemon.cli", "status", "--url",
                                 daemon.base_url], cwd=REPO, stdout=write_end,
                                stderr=subprocess.PIPE, text=True, timeout=60, check=False)
    finally:
        os.close(write_end)
    assert result.returncode == 141
    assert result.stderr == ""


def test_status_of_nothing_says_the_daemon_is_not_running_and_how_to_start_it() -> None:
    port = free_port()  # nothing listens there
    result = run_cli("status", "--url", f"127.0.0.1:{port}")
    assert result.returncode == 69
    assert result.stderr == (
        f"arbiterd status: no daemon answers at http://127.0.0.1:{port} (connection refused): "
        "arbiterd is not running there. Start it: `arbiterd run --sim` (the simulated robot) "
        "or `sudo systemctl start robot.target` (the service); if it runs elsewhere, pass "
        "--url HOST:PORT or --config FILE\n")


@pytest.mark.parametrize("url", ["ftp://robot:8085", "robot:http", "http://"])
def test_status_of_an_address_that_is_none_says_what_to_give(url: str) -> None:
    result = run_cli("status", "--url", url)
    assert result.returncode == 2
    assert result.stderr == (f"arbiterd status: --url {url}: not the daemon's address; give "
                             "HOST:PORT or http://HOST:PORT, e.g. --url 127.0.0.1:8085\n")


def test_status_lines_up_rounds_and_says_why_a_component_is_not_ok() -> None:
    health = {"version": "0.1.0", "status": "degraded", "state": "degraded", "mode": "sim",
              "driver": "mock", "uptime_s": 3725.4, "components": {
                  "control": {"status": "ok", "problem": None, "fault": None},
                  "lidar": {"status": "degraded", "state": "disconnected",
                            "problem": "cannot open /dev/rplidar: it does not exist"},
                  "collision_monitor": {"status": "degraded", "problem": "no scan yet"},
                  "recorder": {"status": "degraded", "problem": "cannot write /x: disk full"},
                  "http": {"status": "ok", "problem": None}}}
    latency = {"commands": 12, "receipt_to_exec_ms": {"count": 12, "p50": 0.01234,
                                                      "p99": 16.4199},
               "tick": {"count": 5000, "late": 3, "missed": 0,
                        "lateness_ms": {"count": 5000, "p50": 3.1658, "p99": 322.2964}}}
    assert format_status(health, latency, "http://robot:8085") == """\
arbiterd 0.1.0 at http://robot:8085: degraded (degraded), sim mode, driver mock, up 1 h 02 min
  control            ok
  lidar              degraded  cannot open /dev/rplidar: it does not exist
  collision_monitor  degraded  no scan yet
  recorder           degraded  cannot write /x: disk full
  http               ok
  commands           12
  receipt->exec      p50 0.012 ms  p99 16.4 ms
  tick lateness      p50 3.17 ms  p99 322 ms  3 late, 0 missed of 5000 ticks"""


def test_safe_stop_in_sim_mode_touches_no_hardware(tmp_path: Path) -> None:
    config = tmp_path / "arbiterd.toml"  # a serial board that is not there
    config.write_text(f'[driver]\ntype = "serial"\n[driver.serial]\nport = "{tmp_path}/no"\n')
    result = run_cli("safe-stop", "--config", str(config), "--sim")
    assert result.returncode == 0, result.stderr
    assert result.stdout == "arbiterd safe-stop: simulated robot (--sim): no hardware to zero\n"
    real = run_cli("safe-stop", "--config", str(config))
    assert real.returncode == 69 and "could not zero the motors" in real.stderr


def test_every_command_is_in_the_readme_table_with_its_options() -> None:
    table = [line for line in (REPO / "README.md").read_text().splitlines()
             if line.startswith("| `arbiterd ")]
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, sub in commands.choices.items():
        rows = [row for row in table if row.startswith(f"| `arbiterd {name} ")
                or row.startswith(f"| `arbiterd {name}`")]
        assert rows, f"`arbiterd {name}` is not in README.md's command table"
        options = {option for action in sub._actions for option in action.option_strings
                   if option.startswith("--") and option != "--help"
                   and action.help != argparse.SUPPRESS and not isinstance(
                       action, argparse._SubParsersAction)}
        if name in ("lidar", "record", "map"):  # their sub-commands carry the options
            continue
        missing = [option for option in options if option not in rows[0].split("|")[1]]
        assert not missing, f"README.md's row of `arbiterd {name}` lacks {missing}"


def test_the_documented_exit_codes_are_the_ones_used() -> None:
    readme = (REPO / "README.md").read_text()
    codes = readme.split("Exit codes:")[1].split("\n\n")[0]
    for code in (EXIT_OK, 1, EXIT_USAGE, EXIT_HARDWARE, EXIT_PORT_IN_USE, EXIT_CONFIG):
        assert re.search(rf"(^|[\s;]){code} ", codes), code


def test_a_refusal_and_a_silent_address_are_said_the_way_a_user_can_act_on() -> None:
    """`arbiterd map save` and `arbiterd mission` report the daemon's own reason for a
    refusal, and which address did not answer."""
    import io
    import urllib.error

    from daemon.api_client import api_failure, call_api
    body = io.BytesIO(b'{"error": "mapping is off: set [mapping] enabled = true"}')
    refusal = urllib.error.HTTPError("http://127.0.0.1:1/api/map/save", 409, "Conflict",
                                     None, body)  # type: ignore[arg-type]
    assert api_failure("http://127.0.0.1:1", refusal) == (
        "the daemon refused (409): mapping is off: set [mapping] enabled = true")
    base = f"http://127.0.0.1:{free_port()}"
    with pytest.raises(OSError) as silent:
        call_api(base, "", "GET", "/api/health")
    assert api_failure(base, silent.value).startswith(f"cannot reach {base}: ")
    assert "refused" in api_failure(base, silent.value)


def test_every_argument_of_every_command_says_what_it_is() -> None:
    """`--help` describes every positional argument too (issue 40: `map build --help` did not
    say what its argument is)."""
    def walk(parser: argparse.ArgumentParser, path: str) -> list[str]:
        bare = []
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    bare += walk(sub, f"{path} {name}")
            elif not action.option_strings and not action.help:
                bare.append(f"{path} {action.dest}")
        return bare

    assert walk(build_parser(), "arbiterd") == []
