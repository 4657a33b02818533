# The systemd units and udev rule: offline verification, hardening score, and their contract.
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.support.deploy import SYSTEMD_DIR, unit_values

SERVICE = SYSTEMD_DIR / "arbiterd.service"
TARGET = SYSTEMD_DIR / "robot.target"
RULES = SYSTEMD_DIR / "99-rplidar.rules"
SYSTEM_UNIT_DIR = Path("/usr/lib/systemd/system")
MAX_EXPOSURE = 2.0


def analyze(*args: str) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("systemd-analyze")
    assert exe, "systemd-analyze missing: ./install.sh dev installs Debian's systemd package"
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=60, check=False)


def service_text() -> str:
    return SERVICE.read_text()


def exec_path(command_line: str) -> str:
    """The executable of an Exec*= line, without systemd's -/@/:/+/! prefixes."""
    return command_line.split()[0].lstrip("-@:+!")


@pytest.fixture
def staging(tmp_path: Path) -> Path:
    """A staging root holding the system's own units plus ours, for `verify --root`."""
    root = tmp_path / "root"
    shutil.copytree(SYSTEM_UNIT_DIR, root / SYSTEM_UNIT_DIR.relative_to("/"), symlinks=True)
    unit_dir = root / "etc/systemd/system"
    unit_dir.mkdir(parents=True)
    shutil.copy(SERVICE, unit_dir)
    shutil.copy(TARGET, unit_dir)
    return root


def place_executables(root: Path, text: str) -> None:
    for key in ("ExecStart", "ExecStopPost"):
        for line in unit_values(text, "Service", key):
            exe = root / exec_path(line).lstrip("/")
            exe.parent.mkdir(parents=True, exist_ok=True)
            exe.write_text("#!/bin/sh\nexit 0\n")
            exe.chmod(0o755)


def verify(root: Path) -> subprocess.CompletedProcess[str]:
    units = ("arbiterd.service", "robot.target")
    return analyze("verify", "--man=no", "--generators=no", f"--root={root}", *units)


def test_units_verify_cleanly_with_exec_start_present(staging: Path) -> None:
    place_executables(staging, service_text())
    result = verify(staging)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "" and result.stderr.strip() == ""


def test_verify_reports_a_missing_exec_start(staging: Path) -> None:
    result = verify(staging)
    assert result.returncode != 0
    assert "/opt/arbiterd/current/venv/bin/arbiterd" in result.stderr
    assert "not executable" in result.stderr


def test_verify_reports_a_misspelt_key(staging: Path) -> None:
    broken = service_text().replace("WatchdogSec=", "WatchDogSecc=")
    (staging / "etc/systemd/system/arbiterd.service").write_text(broken)
    place_executables(staging, broken)
    result = verify(staging)
    # systemd only warns about unknown keys; the clean-verify test above demands no output at all.
    assert "Unknown key 'WatchDogSecc'" in result.stderr


def exposure(unit: Path) -> float:
    result = analyze("security", "--offline=true", "--no-pager", str(unit))
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", result.stdout)
    assert match, result.stdout + result.stderr
    return float(match.group(1))


def test_security_exposure_is_at_most_2(tmp_path: Path) -> None:
    score = exposure(SERVICE)
    assert score <= MAX_EXPOSURE, f"exposure {score} > {MAX_EXPOSURE}"
    threshold = analyze(
        "security", "--offline=true", f"--threshold={int(MAX_EXPOSURE * 10)}", str(SERVICE)
    )
    assert threshold.returncode == 0, threshold.stdout


def test_security_score_reacts_to_weaker_hardening(tmp_path: Path) -> None:
    weak = tmp_path / "arbiterd.service"
    text = service_text()
    for key in ("MemoryDenyWriteExecute", "SystemCallFilter", "ProtectSystem", "ProtectHome"):
        text = re.sub(rf"^{key}=.*$", "", text, flags=re.MULTILINE)
    weak.write_text(text)
    assert exposure(weak) > MAX_EXPOSURE


def test_service_supervision_contract() -> None:
    text = service_text()
    assert unit_values(text, "Service", "Type") == ["notify"]
    assert unit_values(text, "Service", "NotifyAccess") == ["main"]
    assert float(unit_values(text, "Service", "WatchdogSec")[0]) > 0
    assert unit_values(text, "Service", "Restart") == ["on-failure"]
    assert unit_values(text, "Service", "RestartPreventExitStatus") == ["78"]
    assert unit_values(text, "Unit", "StartLimitIntervalSec")
    assert unit_values(text, "Unit", "StartLimitBurst")
    start = unit_values(text, "Service", "ExecStart")[0].split()
    assert start[1:3] == ["run", "--config"] and start[0].endswith("/venv/bin/arbiterd")
    stop_post = unit_values(text, "Service", "ExecStopPost")[0].split()
    assert exec_path(stop_post[0]) == start[0] and stop_post[1] == "safe-stop"


def test_service_has_room_for_connections() -> None:
    """Idle sockets must not take the last descriptor (the default soft limit is 1024)."""
    limit = unit_values(service_text(), "Service", "LimitNOFILE")
    assert limit and int(limit[0]) >= 4096


def test_service_keeps_gpio_serial_pigpiod_and_can_usable() -> None:
    text = service_text()
    assert unit_values(text, "Service", "User") == ["arbiterd"]
    assert not unit_values(text, "Service", "ProcSubset"), "ProcSubset=pid breaks gpiozero"
    assert not unit_values(text, "Service", "PrivateDevices")
    assert not unit_values(text, "Service", "PrivateNetwork")
    allowed = {v.split()[0] for v in unit_values(text, "Service", "DeviceAllow")}
    assert {"char-gpiochip", "/dev/gpiomem", "char-ttyUSB", "char-ttyACM", "char-ttyAMA",
            "char-ttyS", "char-pts"} <= allowed
    families = unit_values(text, "Service", "RestrictAddressFamilies")[0].split()
    assert {"AF_UNIX", "AF_INET", "AF_INET6", "AF_CAN"} <= set(families)
    assert "localhost" in unit_values(text, "Service", "IPAddressAllow")[0].split()
    env = unit_values(text, "Service", "Environment")
    assert "LG_WD=%t/arbiterd" in env
    assert unit_values(text, "Service", "RuntimeDirectory") == ["arbiterd"]
    assert unit_values(text, "Service", "ProtectSystem") == ["strict"]


def test_robot_target_groups_the_daemon() -> None:
    target = TARGET.read_text()
    assert "arbiterd.service" in unit_values(target, "Unit", "Wants")[0].split()
    assert unit_values(target, "Install", "WantedBy") == ["multi-user.target"]
    assert unit_values(service_text(), "Unit", "PartOf") == ["robot.target"]
    assert unit_values(service_text(), "Install", "WantedBy") == ["robot.target"]
    dropin = (SYSTEMD_DIR / "pigpiod.conf").read_text()
    assert unit_values(dropin, "Unit", "Requires") == ["pigpiod.service"]
    assert unit_values(dropin, "Unit", "After") == ["pigpiod.service"]


def rule_field(part: str) -> tuple[str, str]:
    match = re.fullmatch(r'\s*([A-Za-z{}]+)\s*(?:==|\+=|=)\s*"([^"]*)"\s*', part)
    assert match, f"unparsable udev rule field {part!r}"
    return match.group(1), match.group(2)


def test_udev_rule_names_the_rplidar_for_dialout_only() -> None:
    rules = [ln for ln in RULES.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    assert len(rules) == 1
    fields = dict(rule_field(part) for part in rules[0].split(","))
    assert fields == {
        "SUBSYSTEM": "tty", "ATTRS{idVendor}": "10c4", "ATTRS{idProduct}": "ea60",
        "SYMLINK": "rplidar", "GROUP": "dialout", "MODE": "0660",
    }
