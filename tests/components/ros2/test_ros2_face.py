# The ROS 2 face with a real rclpy node, in a private network namespace (loopback only).
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.support.paths import REPO
from tests.support.ros2_probe import unavailable

CHECKS = "tests/ros2_netns/checks_dds.py tests/ros2_netns/checks_face.py"


@pytest.mark.timeout(600)
def test_ros2_face_with_a_real_rclpy_node() -> None:
    """Every check of checks_dds.py and checks_face.py, run by pytest inside `unshare -n`
    with only `lo` up: nothing leaves the machine, and no other test run can share the DDS
    domain (each run has its own network namespace, so the fixed domain ids cannot collide)."""
    why = unavailable()
    if why:
        pytest.skip(why)
    script = (f"ip link set lo up && exec {sys.executable} -m pytest -q -p no:cacheprovider "
              f"{CHECKS}")
    result = subprocess.run(["unshare", "-n", "sh", "-c", script], cwd=REPO, text=True,
                            capture_output=True, timeout=560, check=False,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert result.returncode == 0, result.stdout[-8000:] + result.stderr[-2000:]
