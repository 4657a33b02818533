# `arbiterd run --sim` without a config: the whole simulated robot, each part one line to turn off.
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from daemon import config as config_module
from daemon.config import WHOLE_ROBOT, load_config, whole_robot_toml
from tests.support.net import free_port, http
from tests.support.paths import REPO
from tests.support.wait import wait_for

PARTS = ("mapping", "navigation", "autonomy", "arm", "fetch", "battery", "lidar")


@pytest.fixture(autouse=True)
def no_installed_config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(config_module, "DEFAULT_PATH", tmp_path / "absent.toml")


def test_run_without_a_config_is_the_whole_robot_in_the_apartment() -> None:
    config = load_config(None, sim=True, env={}, whole_robot=True)
    assert config["sim"]["world_file"] == "apartment"
    for section in ("mapping", "navigation", "arm", "fetch", "battery"):
        assert config[section]["enabled"] is True, section
    assert config["arm"]["backend"] == "pca9685"  # the emulated PCA9685 board, as on a robot


def test_each_part_turns_off_with_one_line() -> None:
    config = load_config(None, sim=True, env={"ARBITERD_ARM_ENABLED": "false"},
                         whole_robot=True)
    assert config["arm"]["enabled"] is False and config["mapping"]["enabled"] is True


def test_other_commands_and_a_config_file_keep_the_plain_defaults(tmp_path: Path) -> None:
    assert load_config(None, sim=True, env={})["mapping"]["enabled"] is False
    own = tmp_path / "own.toml"
    own.write_text("[http]\nport = 8090\n")
    assert load_config(own, sim=True, env={}, whole_robot=True)["arm"]["enabled"] is False


def test_the_docs_show_the_same_lines() -> None:
    """docs/simulator.md gives the lines a config file of one's own needs for the same robot."""
    assert whole_robot_toml() in (REPO / "docs" / "simulator.md").read_text()
    assert set(WHOLE_ROBOT) <= {"sim", "mapping", "arm", "battery"}


def test_every_part_is_healthy_on_first_open(tmp_path: Path) -> None:
    if Path("/etc/arbiterd/arbiterd.toml").exists():
        pytest.skip("an installed config stands in for the built-in defaults here")
    port = free_port()
    env = {**os.environ, "ARBITERD_HTTP_HOST": "127.0.0.1", "ARBITERD_HTTP_PORT": str(port),
           "ARBITERD_ROSBRIDGE_HOST": "127.0.0.1", "ARBITERD_ROSBRIDGE_PORT": str(free_port())}
    log = (tmp_path / "daemon.log").open("w")
    proc = subprocess.Popen([sys.executable, "-m", "daemon.cli", "run", "--sim"], cwd=REPO,
                            env=env, stdout=log, stderr=subprocess.STDOUT)

    def components() -> dict[str, str]:
        try:
            _, body = http("GET", f"http://127.0.0.1:{port}/api/health", timeout=2.0)
        except OSError:
            return {}
        return {name: part["status"] for name, part in body["components"].items()}

    try:
        wait_for(lambda: all(components().get(p) == "ok" for p in PARTS),
                 lambda: f"every part ok: {components()}\n"
                 + (tmp_path / "daemon.log").read_text()[-3000:], within_s=60)
    finally:
        proc.terminate()
        proc.wait(15)
        log.close()
