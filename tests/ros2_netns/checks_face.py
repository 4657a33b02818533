# The ROS 2 face against a real rclpy node, in a private netns (tests/components/ros2/).
from __future__ import annotations

import math
import os
import time
from collections.abc import Iterator
from typing import Any

import pytest

from tests.support.daemon_subprocess import DaemonSubprocess
from tests.support.ros2_probe import RosProbe, set_ros_env

TOKEN = "ros2-face-test-token"
#: inside a private network namespace no other run can share the domain; this one is fixed
DOMAIN = int(os.environ.get("ARBITERD_TEST_ROS_DOMAIN", "42"))


def ros2_toml(allow: bool, command_timeout: float = 0.5) -> str:
    return (f'[security]\ntoken = "{TOKEN}"\n'
            f"[ros2]\nenabled = true\ndomain_id = {DOMAIN}\ndiscovery = \"localhost\"\n"
            f"allow_commands = {'true' if allow else 'false'}\n"
            f"command_timeout = {command_timeout}\n")


@pytest.fixture(scope="module")
def probe() -> Iterator[RosProbe]:
    set_ros_env(DOMAIN)
    node = RosProbe()
    yield node
    node.close()


def start_daemon(tmp_path: Any, allow: bool, command_timeout: float = 0.5) -> DaemonSubprocess:
    return DaemonSubprocess(tmp_path, ros2_toml(allow, command_timeout), args=("--sim",)).start()


def ros2_health(daemon: DaemonSubprocess) -> dict[str, Any]:
    _, body = daemon.get("/api/health", token=TOKEN)
    return dict(body["components"]["ros2"])


def truth(daemon: DaemonSubprocess) -> dict[str, float]:
    _, status = daemon.get("/api/status", token=TOKEN)
    return dict(status["ground_truth"])


def moved(a: dict[str, float], b: dict[str, float]) -> float:
    return math.hypot(b["x"] - a["x"], b["y"] - a["y"])


def twist(x: float) -> Any:
    from geometry_msgs.msg import Twist

    message = Twist()
    message.linear.x = x
    return message


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonSubprocess]:
    process = start_daemon(tmp_path_factory.mktemp("ros2-on"), allow=True)
    yield process
    process.__exit__(None, None, None)


def test_scan_arrives_under_sensor_qos_with_every_ray(probe: RosProbe,
                                                      daemon: DaemonSubprocess) -> None:
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import LaserScan

    scans: list[LaserScan] = []
    sub = probe.node.create_subscription(LaserScan, "/scan", scans.append,
                                         qos_profile_sensor_data)
    probe.spin_until(lambda: len(scans) >= 2, "two /scan messages over DDS")
    _, api_scan = daemon.get("/api/scan", token=TOKEN)
    rays = len(api_scan["ranges_m"] if "ranges_m" in api_scan else api_scan["ranges"])
    assert len(scans[-1].ranges) == rays > 0
    probe.node.destroy_subscription(sub)


def test_odom_equals_api_status(probe: RosProbe, daemon: DaemonSubprocess) -> None:
    from nav_msgs.msg import Odometry

    odoms: list[Odometry] = []
    sub = probe.node.create_subscription(Odometry, "/odom", odoms.append, 10)
    probe.spin_until(lambda: odoms, "/odom over DDS")
    _, status = daemon.get("/api/status", token=TOKEN)  # at rest: the pose does not change
    last = odoms[-1].pose.pose.position
    assert (last.x, last.y) == pytest.approx((status["pose"]["x"], status["pose"]["y"]),
                                             abs=1e-9)
    probe.node.destroy_subscription(sub)


def test_graph_lists_the_node_and_its_topics(probe: RosProbe, daemon: DaemonSubprocess) -> None:
    probe.spin_until(lambda: "arbiterd" in probe.node.get_node_names(), "node arbiterd")
    published = dict(probe.node.get_publisher_names_and_types_by_node("arbiterd", "/"))
    taken = dict(probe.node.get_subscriber_names_and_types_by_node("arbiterd", "/"))
    assert published["/scan"] == ["sensor_msgs/msg/LaserScan"]
    assert published["/odom"] == ["nav_msgs/msg/Odometry"]
    assert published["/tf"] == ["tf2_msgs/msg/TFMessage"]
    assert published["/diagnostics"] == ["diagnostic_msgs/msg/DiagnosticArray"]
    assert published["/rosout"] == ["rcl_interfaces/msg/Log"]
    assert taken["/cmd_vel"] == ["geometry_msgs/msg/Twist"]


def test_cmd_vel_moves_the_robot_and_the_deadman_stops_it(probe: RosProbe,
                                                          daemon: DaemonSubprocess) -> None:
    from geometry_msgs.msg import Twist

    pub = probe.node.create_publisher(Twist, "/cmd_vel", 10)
    start = truth(daemon)
    probe.spin_for(1.5, lambda: pub.publish(twist(0.2)))
    after = truth(daemon)
    assert moved(start, after) > 0.05, "a Twist from rclpy moves the simulated robot"
    # the node goes quiet: the deadman (0.5 s) brakes; ground truth comes to rest
    probe.spin_until(lambda: abs(truth(daemon)["v"]) < 1e-3, "the robot stopping", 5.0)
    rest = truth(daemon)
    probe.spin_for(0.5)
    assert moved(rest, truth(daemon)) < 1e-3
    assert ros2_health(daemon)["accepted"] > 0
    probe.node.destroy_publisher(pub)


def test_estop_refuses_dds_commands(probe: RosProbe, daemon: DaemonSubprocess) -> None:
    from geometry_msgs.msg import Twist

    assert daemon.post("/api/estop", {"engaged": True}, token=TOKEN)[0] == 200
    pub = probe.node.create_publisher(Twist, "/cmd_vel", 10)
    before, start = ros2_health(daemon)["refused"]["refused"], truth(daemon)
    probe.spin_until(lambda: (pub.publish(twist(0.2)) or
                              ros2_health(daemon)["refused"]["refused"] > before),
                     "a refusal counted while the e-stop is latched")
    assert moved(start, truth(daemon)) < 1e-3
    assert "e-stop" in ros2_health(daemon)["last_refusal"]
    assert daemon.post("/api/estop", {"engaged": False}, token=TOKEN)[0] == 200
    probe.node.destroy_publisher(pub)


def _refused(daemon: DaemonSubprocess, kind: str) -> int:
    return int(ros2_health(daemon)["refused"][kind])


def test_nan_twist_is_refused(probe: RosProbe, daemon: DaemonSubprocess) -> None:
    from geometry_msgs.msg import Twist

    pub = probe.node.create_publisher(Twist, "/cmd_vel", 10)
    before, start = _refused(daemon, "invalid"), truth(daemon)
    probe.spin_until(lambda: pub.publish(twist(math.nan)) or
                     _refused(daemon, "invalid") > before, "a NaN Twist refused")
    assert moved(start, truth(daemon)) < 1e-3
    probe.node.destroy_publisher(pub)


def test_malformed_sample_is_refused(probe: RosProbe, daemon: DaemonSubprocess) -> None:
    from geometry_msgs.msg import Twist

    pub = probe.node.create_publisher(Twist, "/cmd_vel", 10)
    before, start = _refused(daemon, "malformed"), truth(daemon)
    short = b"\x00\x01\x00\x00" + bytes(12)  # a Twist is 48 bytes after the header
    probe.spin_until(lambda: pub.publish(short) or _refused(daemon, "malformed") > before,
                     "a truncated Twist refused")
    assert moved(start, truth(daemon)) < 1e-3
    probe.node.destroy_publisher(pub)


def test_foreign_type_on_cmd_vel_is_refused(probe: RosProbe, daemon: DaemonSubprocess) -> None:
    from std_msgs.msg import String

    before, start = _refused(daemon, "foreign_type"), truth(daemon)
    pub = probe.node.create_publisher(String, "/cmd_vel", 10)
    probe.spin_until(lambda: pub.publish(String(data="go")) or
                     _refused(daemon, "foreign_type") > before,
                     "a String writer on /cmd_vel counted")
    assert moved(start, truth(daemon)) < 1e-3
    probe.node.destroy_publisher(pub)


def test_a_flood_of_dds_commands_is_held_to_max_rate(probe: RosProbe,
                                                     daemon: DaemonSubprocess) -> None:
    """2000 zero Twists a second for 3 s: the face hands at most [ros2] max_rate (200 a
    second, bursts of 40) to the control loop, refuses the rest as overload, and the daemon
    answers throughout."""
    from geometry_msgs.msg import Twist

    pub = probe.node.create_publisher(Twist, "/cmd_vel", 10)
    probe.spin_until(lambda: pub.publish(twist(0.0)) or ros2_health(daemon)["accepted"] > 0,
                     "the publisher matched")
    before, start = ros2_health(daemon), time.monotonic()
    for burst in range(150):
        for _ in range(20):
            pub.publish(twist(0.0))
        time.sleep(0.01)  # paces the load; nothing waits on it
        if burst % 50 == 0:
            assert ros2_health(daemon)["node"]  # answered while flooded
    after = ros2_health(daemon)
    elapsed = time.monotonic() - start
    assert after["refused"]["overload"] > before["refused"]["overload"]
    assert after["accepted"] - before["accepted"] <= 40 + 200 * (elapsed + 1.0)
    probe.node.destroy_publisher(pub)


def test_same_node_name_elsewhere_refuses_commands(daemon: DaemonSubprocess) -> None:
    from geometry_msgs.msg import Twist

    impostor = RosProbe("arbiterd")
    try:
        pub = impostor.node.create_publisher(Twist, "/cmd_vel", 10)
        start = truth(daemon)
        impostor.spin_until(lambda: ros2_health(daemon)["duplicate_node"],
                            "the daemon seeing a second node /arbiterd")
        before = _refused(daemon, "duplicate_node")
        impostor.spin_until(lambda: pub.publish(twist(0.2)) or
                            _refused(daemon, "duplicate_node") > before,
                            "a command refused while the node name is taken twice")
        assert moved(start, truth(daemon)) < 1e-3
    finally:
        impostor.close()


def test_commands_refused_without_allow_commands(tmp_path: Any, probe: RosProbe,
                                                 daemon: DaemonSubprocess) -> None:
    from geometry_msgs.msg import Twist

    daemon.__exit__(None, None, None)  # the last check: one daemon on the domain at a time
    off = start_daemon(tmp_path, allow=False)
    try:
        pub = probe.node.create_publisher(Twist, "/cmd_vel", 10)
        start = truth(off)
        probe.spin_until(lambda: pub.publish(twist(0.2)) or
                         _refused(off, "not_allowed") > 0,
                         "a command refused with allow_commands = false")
        health = ros2_health(off)
        assert health["allow_commands"] is False and health["accepted"] == 0
        assert "allow_commands = false" in health["last_refusal"]
        assert moved(start, truth(off)) < 1e-3
        probe.node.destroy_publisher(pub)  # the next check needs /cmd_vel without publishers
    finally:
        off.__exit__(None, None, None)


def test_the_last_publisher_going_away_brakes(tmp_path_factory: pytest.TempPathFactory,
                                              probe: RosProbe,
                                              daemon: DaemonSubprocess) -> None:
    """With DDS commands held for 10 s (the longest deadman allowed), the source is dropped
    long before: the reader thread sees the match count fall to zero at the publisher's
    leaving, and the control loop drops the source."""
    from geometry_msgs.msg import Twist

    daemon.__exit__(None, None, None)  # one daemon on the domain at a time
    held = start_daemon(tmp_path_factory.mktemp("ros2-held"), allow=True, command_timeout=10)
    try:
        pub = probe.node.create_publisher(Twist, "/cmd_vel", 10)
        probe.spin_until(lambda: pub.publish(twist(0.2)) or active_source(held) == "ros2",
                         "the robot driven by the DDS command")
        probe.node.destroy_publisher(pub)
        probe.spin_until(lambda: active_source(held) is None, "the source dropped", 5.0)
        probe.spin_until(lambda: abs(truth(held)["v"]) < 1e-3, "the robot stopping")
    finally:
        held.__exit__(None, None, None)


def active_source(daemon: DaemonSubprocess) -> str | None:
    _, status = daemon.get("/api/status", token=TOKEN)
    return status["active_source"]  # type: ignore[no-any-return]
