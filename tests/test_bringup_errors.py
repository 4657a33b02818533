# Errors that say what to do: a busy port names the process holding it, a missing one lists the
# devices present, a late board names reset_wait_s, an old key spelling names the new one.
from __future__ import annotations

import errno
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from base import ports
from base.options import defaults
from daemon.components.http.component import HttpServer
from daemon.components.http.settings import HttpSettings
from daemon.config import ConfigError, load_config
from daemon.listen import PortInUse
from daemon.security import Security
from drivers import DriverFault, create_driver
from drivers.arduino_serial import SerialBridgeDriver
from sim.arduino_emulator import ArduinoEmulator
from sim.rplidar_emulator import RplidarEmulator
from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.paths import REPO
from tests.support.wait import wait_for


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "daemon.cli", *args], capture_output=True,
                          text=True, cwd=REPO, timeout=60)


def test_a_port_the_daemon_holds_is_named_with_the_daemon_and_what_to_do(
        tmp_path: Path) -> None:
    arduino, lidar_link = tmp_path / "arduino", tmp_path / "rplidar"
    toml = (f'[driver]\ntype = "serial"\n[driver.serial]\nport = "{arduino}"\n'
            f'reset_wait_s = 0.05\n[lidar]\nenabled = true\nport = "{lidar_link}"\n')
    with ArduinoEmulator(arduino), RplidarEmulator(lidar_link).start(), \
            DaemonSubprocess(tmp_path, toml) as daemon:
        wait_for(lambda: daemon.get("/api/health")[0] == 200, "the daemon to hold both ports")
        assert daemon.proc is not None
        pid = daemon.proc.pid
        info = cli("lidar", "info", "--port", str(lidar_link))
        assert info.returncode == 69
        assert (f"arbiterd (pid {pid}) is using {lidar_link} — stop the service (sudo "
                "systemctl stop arbiterd) or use `arbiterd status`") in info.stderr
        check = cli("check", "--config", str(daemon.config_path))
        assert check.returncode == 69
        assert (f"[driver] serial: cannot open serial port {arduino}: arbiterd (pid {pid}) is "
                f"using {arduino}") in check.stdout
        assert f"[lidar] {lidar_link}: cannot open {lidar_link}: arbiterd (pid {pid})" \
            in check.stdout
        assert daemon.get("/api/health")[0] == 200, "probing must not disturb the daemon"


def test_a_process_run_from_a_clone_named_arbiterd_is_not_called_the_daemon(
        tmp_path: Path) -> None:
    """The default `git clone …/arbiterd`: pytest, a script or a venv tool started from it
    has "arbiterd" in its command line, but only `arbiterd run` is the daemon."""
    clone = tmp_path / "arbiterd"
    clone.mkdir()
    script = clone / "hold.py"
    script.write_text("import sys\nheld = open(sys.argv[1], 'rb')\nprint('holding', flush=True)"
                      "\nsys.stdin.read()\n")
    device = tmp_path / "ttyUSB0"
    device.touch()
    with subprocess.Popen([sys.executable, str(script), str(device)], cwd=clone, text=True,
                          stdin=subprocess.PIPE, stdout=subprocess.PIPE) as holder:
        assert holder.stdout is not None and holder.stdin is not None
        assert holder.stdout.readline() == "holding\n"
        comm = Path(f"/proc/{holder.pid}/comm").read_text().strip()
        text = ports.busy_message(device)
        holder.stdin.close()
    assert text == f"{comm} (pid {holder.pid}) is using {device} — close it first"


@pytest.mark.parametrize(("argv", "command"), [
    (["/opt/arbiterd/current/venv/bin/python3", "/opt/arbiterd/current/venv/bin/arbiterd",
      "run", "--config", "/etc/arbiterd/arbiterd.toml"], "run"),
    (["/home/me/arbiterd/.venv/bin/python", "-m", "daemon.cli", "run", "--sim"], "run"),
    (["python3", "-u", "-X", "dev", "-Bm", "daemon.cli", "run"], "run"),
    (["/usr/local/bin/arbiterd", "run"], "run"),
    (["/home/me/arbiterd/.venv/bin/python", "-m", "pytest", "/home/me/arbiterd/tests"], None),
    (["/home/me/arbiterd/.venv/bin/python", "/home/me/arbiterd/.venv/bin/pytest", "-x"], None),
    (["python3", "-c", "print('arbiterd run')"], None),
    (["/home/me/arbiterd/tools/flash", "run"], None),
    (["python3", "/home/me/arbiterd/.venv/bin/arbiterd", "lidar", "info"], "lidar"),
])
def test_the_daemon_is_recognised_by_its_command_line_not_by_a_path(
        argv: list[str], command: str | None) -> None:
    assert ports.arbiterd_command(argv) == command
    assert ports.is_daemon(argv) == (command == "run")


def test_a_second_daemon_names_the_first_and_how_to_choose_other_ports(tmp_path: Path) -> None:
    with DaemonSubprocess(tmp_path) as first:
        assert first.proc is not None
        pid = first.proc.pid
        again = cli("run", "--config", str(first.config_path))
        assert again.returncode == 75, again.stderr
        assert (f"port {first.ws_port} ([rosbridge] port) is in use by arbiterd (pid {pid}); "
                f"port {first.http_port} ([http] port) is in use by arbiterd (pid {pid}): "
                "another arbiterd is running (`arbiterd status` shows it; the service stops "
                "with sudo systemctl stop robot.target), or run this one on other ports: "
                "arbiterd run --http-port PORT --ws-port PORT (or [http] port and [rosbridge] "
                "port in its config)") in again.stderr
        assert "Errno" not in again.stderr and "Traceback" not in again.stderr
        (tmp_path / "second").mkdir()
        second = DaemonSubprocess(tmp_path / "second")
        second.config_path.write_text(first.config_path.read_text())  # the same ports...
        second.args = ("--http-port", str(second.http_port), "--ws-port", str(second.ws_port))
        with second:  # ...and the options choose others
            code, health = second.get("/api/health")
            assert code == 200, health
            assert health["components"]["http"]["port"] == second.http_port
            with socket.create_connection(("127.0.0.1", second.ws_port), timeout=5):
                pass
            assert second.stop() == 0
        assert first.get("/api/health")[0] == 200


def test_a_port_another_program_holds_is_named_and_nothing_starts(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        toml = tmp_path / "a.toml"
        toml.write_text(f'[http]\nhost = "127.0.0.1"\nport = {port}\n[rosbridge]\nenabled = '
                        f'false\n[driver.mock]\nlog_file = "{tmp_path / "wheels.log"}"\n')
        done = cli("run", "--config", str(toml))
    me = Path("/proc/self/comm").read_text().strip()
    assert done.returncode == 75
    assert (f"cannot start: port {port} ([http] port) is in use by {me} (pid {os.getpid()}): "
            "stop it, or run this one on other ports: arbiterd run --http-port PORT") \
        in done.stderr
    assert not (tmp_path / "wheels.log").exists(), "the driver was opened"


async def test_a_port_taken_between_the_check_and_the_bind_is_explained() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        server = HttpServer(HttpSettings.from_values(
            defaults(HttpSettings.OPTIONS) | {"host": "127.0.0.1", "port": port}), Security(""))
        with pytest.raises(PortInUse) as caught:
            await server.start()
        await server.stop()
    assert str(caught.value).startswith(f"port {port} ([http] port) is in use by ")


def test_a_port_option_that_is_no_port_is_a_usage_error() -> None:
    done = cli("run", "--http-port", "80800")
    assert done.returncode == 2
    assert "argument --http-port: '80800' is not a TCP port: give a number from 1 to 65535" \
        in done.stderr


async def test_a_missing_port_lists_the_devices_present_and_the_dialout_hint(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "ttyACM0").touch()
    monkeypatch.setattr(ports, "CANDIDATE_PATTERNS", (str(tmp_path / "ttyACM*"),))
    driver = SerialBridgeDriver({"port": str(tmp_path / "arduino")}, max_wheel_speed=10.0)
    with pytest.raises(DriverFault) as caught:
        await driver.open()
    assert str(caught.value) == (
        f"cannot open serial port {tmp_path / 'arduino'}: {tmp_path / 'arduino'} does not "
        f"exist; serial devices present: {tmp_path / 'ttyACM0'}; the user running arbiterd "
        "needs the dialout group to open serial ports (sudo usermod -aG dialout $USER, then "
        "log in again)")


def test_no_permission_gives_the_dialout_hint(tmp_path: Path) -> None:
    device = tmp_path / "ttyUSB0"
    device.touch()
    text = ports.open_error(device, OSError(errno.EACCES, "Permission denied"))
    assert text.startswith("permission denied; the user running arbiterd needs the dialout")


def test_check_still_exits_69_without_the_board(tmp_path: Path) -> None:
    path = tmp_path / "a.toml"
    path.write_text(f'[driver]\ntype = "serial"\n[driver.serial]\nport = "{tmp_path / "x"}"\n')
    done = cli("check", "--config", str(path))
    assert done.returncode == 69 and "does not exist; serial devices present" in done.stdout


async def test_the_emulator_and_the_driver_connect_on_their_defaults(tmp_path: Path) -> None:
    """The standalone emulator's bootloader takes 2.0 s (its --boot default, like an Uno) and
    the driver waits reset_wait_s = 2.0 s: it keeps asking until the board answers."""
    with ArduinoEmulator(tmp_path / "arduino", boot_s=2.0) as board:
        driver = SerialBridgeDriver({"port": str(board.link)}, max_wheel_speed=10.0)
        await driver.open()
        try:
            assert driver.health()["status"] == "ok"
        finally:
            await driver.close()


async def test_a_board_answering_garbage_points_at_the_baud_rate(tmp_path: Path) -> None:
    with ArduinoEmulator(tmp_path / "arduino") as board:
        board.garbage = True
        driver = SerialBridgeDriver({"port": str(board.link), "reset_wait_s": 0.0,
                                     "boot_timeout_s": 0.3}, max_wheel_speed=10.0)
        with pytest.raises(DriverFault, match=r"only garbled replies to 'e' .*reset_wait_s "
                                              r"\(now 0\); else check baudrate \(57600"):
            await driver.open()


def test_old_spellings_of_the_direction_keys_name_the_new_ones(tmp_path: Path) -> None:
    path = tmp_path / "old.toml"
    path.write_text("[driver.serial]\ninvert_left = true\n[driver.odrive_can]\n"
                    "right_inverted = false\n[driver.pigpio]\nleft_encoder_invert = true\n")
    with pytest.raises(ConfigError) as caught:
        load_config(path, env={})
    problems = "\n".join(caught.value.problems)
    assert ("[driver.serial] invert_left: renamed; did you mean left_motor_inverted = true and "
            "left_encoder_inverted = true?") in problems
    assert "[driver.odrive_can] right_inverted: renamed; did you mean right_motor_inverted" \
        in problems
    assert "[driver.pigpio] left_encoder_invert: renamed; did you mean left_encoder_inverted?" \
        in problems
    with pytest.raises(ValueError, match=r"\[driver.l298n\] left_invert: renamed; did you mean "
                                         r"left_motor_inverted\?"):
        create_driver("l298n", {"left_invert": True}, max_wheel_speed=1.0)
