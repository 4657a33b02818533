# Hardware missing at boot is not fatal: `arbiterd run` comes up with the driver in error, keeps
# retrying with back-off, and drives once the device appears, after a fresh command.
from __future__ import annotations

import time
from pathlib import Path

from sim.arduino_emulator import ArduinoEmulator
from sim.motor_model import MotorPair
from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.wait import wait_for


def test_an_arduino_plugged_in_after_boot_drives_after_a_fresh_command(tmp_path: Path) -> None:
    link = tmp_path / "arduino"
    toml = (f'[driver]\ntype = "serial"\n[driver.serial]\nport = "{link}"\n'
            f'reset_wait_s = 0.05\n[control]\nreconnect_min_s = 0.1\nreconnect_max_s = 0.4\n')
    with DaemonSubprocess(tmp_path, toml) as daemon:
        code, health = daemon.get("/api/health")
        assert code == 503 and health["driver"] == "serial", health
        fault = health["components"]["control"]["fault"]
        assert fault.startswith("serial driver not available") and str(link) in fault, fault
        code, refused = daemon.post("/api/cmd_vel", {"linear": {"x": 0.2}})
        assert code == 409 and "driver fault" in refused["error"], refused
        def attempts() -> int:
            return int(daemon.get("/api/health")[1]["components"]["control"][
                "reconnect_attempts"])

        def naming_the_board() -> list[str]:  # but the daemon's state lines (not per attempt)
            return [line for line in daemon.log().splitlines()
                    if str(link) in line and "state:" not in line]

        wait_for(lambda: attempts() >= 1, "a reconnect attempt")
        said = naming_the_board()
        wait_for(lambda: attempts() >= 4, "more reconnect attempts")
        assert daemon.proc is not None and daemon.proc.poll() is None  # no restart loop
        assert naming_the_board() == said, "the missing board is logged once, not per attempt"

        pair = MotorPair()
        with ArduinoEmulator(link, pair) as board:
            wait_for(lambda: daemon.get("/api/health")[0] == 200, "the driver to connect",
                     within_s=10)
            time.sleep(0.3)
            assert pair.targets() == (0.0, 0.0), "moved before a fresh command"
            assert all(c.text in ("e", "m 0 0") or c.text.startswith("u ")
                       for c in board.firmware.history), list(board.firmware.history)
            assert daemon.post("/api/cmd_vel", {"linear": {"x": 0.2}})[0] == 200
            wait_for(lambda: min(pair.targets()) > 1.0, "the wheels to drive", within_s=5)
        assert daemon.stop() == 0
    assert "driver reconnected; wheels stay still until a fresh command" in daemon.log()
