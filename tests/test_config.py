# Strict configuration: unknown keys, wrong types, ranges, env overrides, exit code 78.
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from daemon.config import ConfigError, env_name, load_config
from tests.support.paths import REPO


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "arbiterd.toml"
    path.write_text(text)
    return path


def problems_of(path: Path, env: dict[str, str] | None = None) -> list[str]:
    with pytest.raises(ConfigError) as info:
        load_config(path, env=env or {})
    return info.value.problems


def test_builtin_defaults_run_the_simulated_robot(tmp_path: Path) -> None:
    config = load_config(None, env={})
    assert config.sim
    assert config["control"]["cmd_vel_timeout"] == 0.5
    assert config["control"]["update_rate"] == 50.0
    assert config["robot"]["wheel_separation"] == 0.30
    assert config["http"]["port"] == 8085 and config["rosbridge"]["port"] == 9090


def test_explicit_file_is_hardware_mode_unless_sim_flag(tmp_path: Path) -> None:
    path = write(tmp_path, "[driver]\ntype = \"mock\"\n")
    assert not load_config(path, env={}).sim
    assert load_config(path, sim=True, env={}).sim


def test_typo_in_key_names_key_file_and_suggestion(tmp_path: Path) -> None:
    path = write(tmp_path, "[control]\ncmd_vel_timout = 0.3\n")
    [problem] = problems_of(path)
    assert str(path) in problem
    assert "[control] cmd_vel_timout: unknown key" in problem
    assert "did you mean 'cmd_vel_timeout'" in problem


def test_every_problem_is_reported_at_once(tmp_path: Path) -> None:
    path = write(tmp_path, """
[robot]
wheel_radius = -0.05
wheel_separation = "wide"
[limits]
linear.x.max_velocity = 1e9
linear.x.max_acceleraton = 1.0
[driver]
type = "stepper"
[nonsense]
a = 1
""")
    problems = problems_of(path)
    joined = "\n".join(problems)
    assert len(problems) == 6, joined
    assert "[robot] wheel_radius: must be > 0.0" in joined
    assert "[robot] wheel_separation: expected a number, got str 'wide'" in joined
    assert "[limits] linear.x.max_velocity: must be <= 100.0" in joined
    assert "[limits] linear.x.max_acceleraton: unknown key" in joined
    assert "[driver] type: must be one of" in joined and "'stepper'" in joined
    assert "[nonsense]: unknown section" in joined


@pytest.mark.parametrize(("text", "expected"), [
    pytest.param("[driver.mock]\nencoders = \"yes\"\nhistroy = 5\n",
                 ["[driver.mock] encoders: expected true/false",
                  "[driver.mock] histroy: unknown key"],
                 id="driver subsection validated by the driver"),
    pytest.param("[limits]\nlinear.x.max_velocity = nan\nangular.z.max_velocity = inf\n",
                 ["linear.x.max_velocity: must be a finite number", "angular.z.max_velocity"],
                 id="non-finite values refused"),
])
def test_bad_values_are_named(tmp_path: Path, text: str, expected: list[str]) -> None:
    joined = "\n".join(problems_of(write(tmp_path, text)))
    missing = [fragment for fragment in expected if fragment not in joined]
    assert not missing, joined


def test_dotted_and_nested_limit_keys_are_the_same(tmp_path: Path) -> None:
    path = write(tmp_path, "[limits.linear.x]\nmax_velocity = 0.7\n")
    assert load_config(path, env={})["limits"]["linear.x.max_velocity"] == 0.7


def test_env_overrides_a_key_and_rejects_unknown(tmp_path: Path) -> None:
    path = write(tmp_path, "[control]\ncmd_vel_timeout = 0.3\n")
    assert env_name("limits", "linear.x.max_velocity") == "ARBITERD_LIMITS_LINEAR_X_MAX_VELOCITY"
    config = load_config(path, env={"ARBITERD_CONTROL_CMD_VEL_TIMEOUT": "0.8",
                                    "ARBITERD_LIMITS_LINEAR_X_MAX_VELOCITY": "1.5",
                                    "ARBITERD_ROBOT_NAME": "rover"})
    assert config["control"]["cmd_vel_timeout"] == 0.8
    assert config["limits"]["linear.x.max_velocity"] == 1.5
    assert config["robot"]["name"] == "rover"
    problems = problems_of(path, env={"ARBITERD_CONTROL_CMD_VEL_TIMOUT": "1"})
    assert "ARBITERD_CONTROL_CMD_VEL_TIMOUT: no such config key" in problems[0]
    problems = problems_of(path, env={"ARBITERD_CONTROL_UPDATE_RATE": "fast"})
    assert "[control] update_rate: expected a number" in problems[0]


def test_an_old_section_name_loads_with_one_deprecation_warning(tmp_path: Path) -> None:
    path = write(tmp_path, '[record]\nenabled = true\ndirectory = "/tmp/rec"\n')
    config = load_config(path, env={})
    assert config["recorder"]["enabled"] and config["recorder"]["directory"] == "/tmp/rec"
    assert "record" not in config.sections
    assert config.warnings == [f"{path}: [record] is now [recorder]; rename the section in "
                               f"{path}"]
    renamed = write(tmp_path, '[recorder]\nenabled = true\ndirectory = "/tmp/rec"\n')
    config_now = load_config(renamed, env={})
    assert config_now["recorder"] == config["recorder"] and not config_now.warnings


def test_an_old_and_a_new_section_name_in_one_file_is_an_error(tmp_path: Path) -> None:
    path = write(tmp_path, "[recorder]\nenabled = true\n[record]\nenabled = false\n")
    [problem] = problems_of(path)
    assert f"{path}: [record] and [recorder] are the same section" in problem
    assert "keep [recorder] only" in problem


def test_a_key_of_an_old_section_name_is_still_checked(tmp_path: Path) -> None:
    path = write(tmp_path, "[record]\nqueue_size = 5\nenabeld = true\n")
    assert problems_of(path) == [
        f"{path}: [recorder] queue_size: must be >= 100, got 5",
        f"{path}: [recorder] enabeld: unknown key (did you mean 'enabled'?)"]


def test_env_overrides_under_the_old_and_the_new_section_name(tmp_path: Path) -> None:
    path = write(tmp_path, "[driver]\ntype = \"mock\"\n")
    new = load_config(path, env={"ARBITERD_RECORDER_QUEUE_SIZE": "500"})
    assert new["recorder"]["queue_size"] == 500 and not new.warnings
    old = load_config(path, env={"ARBITERD_RECORD_QUEUE_SIZE": "600",
                                 "ARBITERD_RECORD_ENABLED": "true"})
    assert old["recorder"]["queue_size"] == 600 and old["recorder"]["enabled"]
    assert old.warnings == [
        "environment variable ARBITERD_RECORD_QUEUE_SIZE: [record] is now [recorder]; use "
        "ARBITERD_RECORDER_QUEUE_SIZE",
        "environment variable ARBITERD_RECORD_ENABLED: [record] is now [recorder]; use "
        "ARBITERD_RECORDER_ENABLED"]
    [both] = problems_of(path, env={"ARBITERD_RECORD_QUEUE_SIZE": "600",
                                    "ARBITERD_RECORDER_QUEUE_SIZE": "500"})
    assert "ARBITERD_RECORD_QUEUE_SIZE and ARBITERD_RECORDER_QUEUE_SIZE both set" in both
    [bad] = problems_of(path, env={"ARBITERD_RECORD_QUEUE_SIZE": "5"})
    assert bad.startswith("environment variable ARBITERD_RECORD_QUEUE_SIZE=5: [recorder] "
                          "queue_size: must be >= 100"), bad
    [typo] = problems_of(path, env={"ARBITERD_RECORD_QUEUE_SIZ": "500"})
    assert "ARBITERD_RECORD_QUEUE_SIZ: no such config key" in typo


def test_token_file(tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token_file.write_text("s3cret-t0ken\n")
    path = write(tmp_path, f"[security]\ntoken_file = \"{token_file}\"\n")
    assert load_config(path, env={}).token == "s3cret-t0ken"
    path = write(tmp_path, f"[security]\ntoken_file = \"{tmp_path / 'missing'}\"\n")
    assert "token_file: cannot read" in problems_of(path)[0]


def test_a_short_token_is_refused(tmp_path: Path) -> None:
    """A 1-character token was accepted (8 555 guesses a second would find it at once)."""
    for line in ('token = "x"', 'token = "eleven-char"'):
        [problem] = problems_of(write(tmp_path, f"[security]\n{line}\n"))
        assert "too short to keep anyone out; at least 12" in problem, problem
    token_file = tmp_path / "token"
    token_file.write_text("abc\n")
    [problem] = problems_of(write(tmp_path, f"[security]\ntoken_file = \"{token_file}\"\n"))
    assert "3 characters is too short" in problem
    assert load_config(write(tmp_path, '[security]\ntoken = "twelve-chars"\n'),
                       env={}).token == "twelve-chars"


def test_bad_toml_names_the_line(tmp_path: Path) -> None:
    path = write(tmp_path, "[control]\nupdate_rate = = 5\n")
    [problem] = problems_of(path)
    assert "not valid TOML" in problem and "line 2" in problem


def test_deadman_disabled_warns(tmp_path: Path) -> None:
    path = write(tmp_path, "[control]\ncmd_vel_timeout = 0\n")
    assert any("deadman stop is DISABLED" in w for w in load_config(path, env={}).warnings)


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "daemon.cli", *args], cwd=REPO,
                          capture_output=True, text=True, timeout=60)


def test_run_with_a_typo_exits_78_naming_key_and_file(tmp_path: Path) -> None:
    path = write(tmp_path, "[http]\nprot = 8085\n")
    result = run_cli("run", "--config", str(path))
    assert result.returncode == 78
    assert f"{path}: [http] prot: unknown key (did you mean 'port'?)" in result.stderr


def test_run_with_a_missing_explicit_config_exits_78(tmp_path: Path) -> None:
    result = run_cli("run", "--config", str(tmp_path / "nope.toml"))
    assert result.returncode == 78
    assert "config file not found" in result.stderr


def test_check_lists_all_problems_and_prints_effective_config(tmp_path: Path) -> None:
    bad = write(tmp_path, "[robot]\nwheel_radius = 0\n[control]\nupdate_rat = 50\n")
    result = run_cli("check", "--config", str(bad))
    assert result.returncode == 78
    assert result.stdout.startswith("arbiterd check: FAILED: configuration error (2 problems)")
    assert "[robot] wheel_radius: must be > 0.0" in result.stdout
    assert "[control] update_rat: unknown key" in result.stdout
    good = write(tmp_path, "[driver]\ntype = \"mock\"\n[robot]\nwheel_radius = 0.04\n")
    result = run_cli("check", "--verbose", "--config", str(good))
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(f"arbiterd check: ok: {good}: configuration valid and the "
                                    "hardware answers")
    assert "wheel_radius = 0.04" in result.stdout  # the effective config, with --verbose


def test_check_shows_the_deprecation_of_an_old_section_name_once(tmp_path: Path) -> None:
    path = write(tmp_path, "[driver]\ntype = \"mock\"\n[record]\nenabled = false\n")
    result = run_cli("check", "--no-probe", "--config", str(path))
    assert result.returncode == 0, result.stdout + result.stderr
    lines = [line for line in result.stdout.splitlines() if "[record]" in line]
    assert lines == [f"warning: {path}: [record] is now [recorder]; rename the section in "
                     f"{path}"]


def test_usage_error_exits_2() -> None:
    assert run_cli("frobnicate").returncode == 2


def test_example_config_documents_every_key_and_loads(tmp_path: Path) -> None:
    from daemon.example_config import render

    example = REPO / "systemd" / "arbiterd.toml.example"
    assert example.read_text() == render(), (
        "regenerate it: python -m daemon.example_config > systemd/arbiterd.toml.example")
    config = load_config(example, env={})
    assert config["driver"]["type"] == "serial" and config["lidar"]["enabled"]
