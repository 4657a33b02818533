# roslib 2.x (and 1.x) on Node against `arbiterd run --sim` over a real WebSocket.
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.support.daemon_subprocess import DaemonSubprocess

HERE = Path(__file__).resolve().parent
NODE = shutil.which("node")


def _require_roslib() -> None:
    """Node and the locked roslib install are prerequisites (`.ci/run` runs `npm ci`)."""
    if NODE is None:
        pytest.fail("node is not installed; run ./install.sh dev")
    for package in ("roslib", "roslib1"):
        if not (HERE / "node_modules" / package / "package.json").exists():
            pytest.fail(f"tests/interop/node_modules/{package} is missing; run "
                        "`npm ci` in tests/interop (./install.sh dev does it)")


def _lidar_running(daemon: DaemonSubprocess) -> bool:
    _, health = daemon.get("/api/health")
    if not isinstance(health, dict):
        return False
    lidar = health.get("components", {}).get("lidar") or {}
    return bool(lidar.get("status") == "ok")


@pytest.mark.parametrize("flavour", ["roslib2", "roslib1"])
def test_roslib_drives_the_simulated_robot(tmp_path: Path, flavour: str) -> None:
    _require_roslib()
    assert NODE is not None
    with DaemonSubprocess(tmp_path, args=("--sim",)) as daemon:
        args = [NODE, str(HERE / "roslib_client.mjs"), f"ws://127.0.0.1:{daemon.ws_port}/"]
        if flavour == "roslib1":
            args.append("--v1")
        expect_scan = _lidar_running(daemon)
        if expect_scan:
            args.append("--expect-scan")
        result = subprocess.run(args, cwd=HERE, capture_output=True, text=True, timeout=60)
        steps = {}
        for line in result.stdout.splitlines():
            if line.startswith("{"):
                record = json.loads(line)
                steps[record["step"]] = record
        assert result.returncode == 0, (
            f"roslib client failed:\n{result.stdout}\n{result.stderr}\n--- daemon log ---\n"
            f"{daemon.log()}")
        assert steps["connected"]["version"] == (1 if flavour == "roslib1" else 2)
        assert steps["drove"]["to"] - steps["drove"]["from"] > 0.05
        assert set(steps["drove"]["stamp"]) == {"sec", "nanosec"}
        assert steps["services"]["type"] == "nav_msgs/msg/Odometry"
        assert steps["status"]["level"] == "error" and "linear.x" in steps["status"]["msg"]
        assert str(steps["status"]["id"]).startswith("publish:/cmd_vel:")
        assert steps["alive"]["topics"] >= 8
        assert steps["done"]["ok"] is True
        if expect_scan:
            assert steps["scan"]["rays"] > 0
        else:
            assert steps["scan"]["subscribed"] is True
        assert daemon.stop() == 0


#: a PCA9685 count at 50 Hz (4.9 µs of the 2000 µs pulse range) in rad and in m of the gripper
ONE_STEP = 1e6 / (50.03 * 4096) / 2000
ARM = '[sim]\nlidar = false\n[arm]\nenabled = true\nbackend = "pca9685"\n' \
    'max_speed = [10.0, 10.0, 10.0, 0.35]\n'


def test_roslib_moves_the_arm(tmp_path: Path) -> None:
    """/arm/pose and the seed's joint command topics from roslib drive the emulated PCA9685
    servos; /joint_states (what their pulses mean) converges to each target."""
    _require_roslib()
    assert NODE is not None
    with DaemonSubprocess(tmp_path, ARM, args=("--sim",)) as daemon:
        result = subprocess.run(
            [NODE, str(HERE / "roslib_arm.mjs"), f"ws://127.0.0.1:{daemon.ws_port}/",
             str(ONE_STEP * 3.1416), str(ONE_STEP * 0.035)],
            cwd=HERE, capture_output=True, text=True, timeout=60)
        steps = {json.loads(line)["step"]: json.loads(line)
                 for line in result.stdout.splitlines() if line.startswith("{")}
        assert result.returncode == 0, (
            f"roslib client failed:\n{result.stdout}\n{result.stderr}\n--- daemon log ---\n"
            f"{daemon.log()}")
        assert daemon.stop() == 0
    assert steps["pregrasp"]["name"] == ["arm_joint1", "arm_joint2", "arm_joint3",
                                         "left_finger_joint", "right_finger_joint"]
    assert steps["joints"]["position"] == pytest.approx([0.3, -0.4, 0.6, 0.01, 0.01],
                                                        abs=ONE_STEP * 3.1416)
    assert steps["refused"]["level"] == "error"
    assert "no pose named 'wave'" in steps["refused"]["msg"]
