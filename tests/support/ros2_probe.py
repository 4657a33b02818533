# Test harness: a real rclpy (ROS 2 Jazzy) node beside a daemon, spun in the test's own thread.
from __future__ import annotations

import os
import platform
import shutil
import subprocess
import time
from collections.abc import Callable
from typing import Any

from tests.support.wait import Deadline


def unavailable() -> str | None:
    """Why the ROS 2 face cannot be tested here (None when it can)."""
    if platform.machine() != "x86_64":
        return "the ROS 2 Jazzy wheels on PyPI are x86_64 Linux only"
    for module in ("rclpy", "cyclonedds"):
        try:
            __import__(module)
        except ImportError:
            return f"{module} is not installed (./install.sh dev installs the ros2 extras)"
    if shutil.which("unshare") is None:
        return "no unshare(1) for a private network namespace"
    probe = subprocess.run(["unshare", "-n", "true"], capture_output=True, check=False)
    if probe.returncode != 0:
        return "cannot make a private network namespace here (unshare -n needs privileges)"
    return None


class RosProbe:
    """One rclpy node (``probe``) with helpers to wait on what it receives."""

    def __init__(self, name: str = "probe") -> None:
        import rclpy

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, condition: Callable[[], Any], what: str, within_s: float = 15.0) -> Any:
        deadline = Deadline(what, within_s)
        while not (value := condition()):
            self.executor.spin_once(timeout_sec=0.05)
            deadline.check()
        return value

    def spin_for(self, seconds: float, each: Callable[[], None] | None = None) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if each is not None:
                each()
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.context)


def ros_env(domain: int) -> dict[str, str]:
    return {"ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


def set_ros_env(domain: int) -> None:
    os.environ.update(ros_env(domain))
