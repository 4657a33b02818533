# The ROS 2 face with a real rclpy node, in a private network namespace (loopback only).
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.paths import REPO
from tests.support.ros2_probe import unavailable

CHECKS = "tests/ros2_netns/checks_dds.py tests/ros2_netns/checks_face.py"
#: the venv with ROS 2 Kilted's rclpy that ./install.sh dev makes (kilted-requirements.txt)
KILTED_VENV = Path(os.environ.get("ARBITERD_KILTED_VENV", REPO / ".venv-kilted"))


@pytest.mark.timeout(600)
def test_ros2_face_with_a_real_rclpy_node() -> None:
    """Every check of checks_dds.py and checks_face.py, run by pytest inside `unshare -n`
    with only `lo` up: nothing leaves the machine, and no other test run can share the DDS
    domain (each run has its own network namespace, so the fixed domain ids cannot collide)."""
    in_netns(CHECKS, {})


@pytest.mark.timeout(300)
def test_ros2_face_with_real_kilted_and_jazzy_nodes() -> None:
    """checks_peers.py in its own namespace: a node of ROS 2 Kilted (from .venv-kilted, run as
    a subprocess: Kilted's and Jazzy's wheels both install `rclpy`) and one of Jazzy each read
    /scan and drive, see the face's type hashes equal to their own, and log no warning."""
    kilted = KILTED_VENV / "bin" / "python"
    if not kilted.exists():
        pytest.skip(f"no ROS 2 Kilted venv at {KILTED_VENV} (./install.sh dev makes it)")
    in_netns("tests/ros2_netns/checks_peers.py", {"ARBITERD_KILTED_PYTHON": str(kilted)})


@pytest.mark.timeout(300)
def test_ros2_face_with_dds_security() -> None:
    """checks_security.py in its own namespace: with [ros2] security a reader holding an
    enclave of the same keystore receives /scan, one without receives nothing (and receives
    from the face without security)."""
    in_netns("tests/ros2_netns/checks_security.py", {})


def in_netns(checks: str, env: dict[str, str]) -> None:
    """pytest of ``checks`` inside `unshare -n` with only `lo` up; fails with their output."""
    why = unavailable()
    if why:
        pytest.skip(why)
    script = (f"ip link set lo up && exec {sys.executable} -m pytest -q -rs -p no:cacheprovider "
              f"{checks}")
    result = subprocess.run(["unshare", "-n", "sh", "-c", script], cwd=REPO, text=True,
                            capture_output=True, timeout=560, check=False,
                            env={**os.environ, "PYTHONUNBUFFERED": "1", **env})
    assert result.returncode == 0, result.stdout[-8000:] + result.stderr[-2000:]
