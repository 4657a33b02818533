# A ROS 2 node of any release (Jazzy, Kilted): reads /scan and /odom, drives; prints what it saw.
"""Run by the interpreter of a venv holding that release's rclpy (only rclpy and the message
packages are imported, never arbiterd): ``python rclpy_peer.py [--drive SECONDS]``. The domain
and discovery range come from ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE. It prints one
JSON line: the messages received, the rays of the last scan, the type name and type hash the
node /arbiterd announces for /scan beside this node's own, and the RMW."""
from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

NAME = "peer"


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--drive", type=float, default=0.0,
                        help="publish /cmd_vel until /odom has moved this far, m")
    parser.add_argument("--within", type=float, default=40.0)
    args = parser.parse_args()

    import rclpy
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from rclpy.utilities import get_rmw_implementation_identifier
    from sensor_msgs.msg import LaserScan

    rclpy.init()
    node = rclpy.create_node(NAME)
    scans: list[Any] = []
    odoms: list[Any] = []
    node.create_subscription(LaserScan, "/scan", scans.append, qos_profile_sensor_data)
    node.create_subscription(Odometry, "/odom", odoms.append, 10)
    end = time.monotonic() + args.within
    while (len(scans) < 2 or not odoms) and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    report: dict[str, Any] = {
        "rmw": get_rmw_implementation_identifier(), "scans": len(scans), "odoms": len(odoms),
        "rays": len(scans[-1].ranges) if scans else 0,
        "scan_writers": _endpoints(node.get_publishers_info_by_topic("/scan")),
        "scan_own": _endpoints(node.get_subscriptions_info_by_topic("/scan"), own=True),
        "cmd_vel_readers": _endpoints(node.get_subscriptions_info_by_topic("/cmd_vel")),
    }
    if args.drive > 0:
        report["driven"] = _drive(rclpy, node, Twist, lambda: _moved(odoms) >= args.drive,
                                  time.monotonic() + args.within)
    print(json.dumps(report), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


def _endpoints(infos: list[Any], own: bool = False) -> list[dict[str, str]]:
    """The endpoints of other nodes (or this node's own): their node, type and type hash."""
    return [{"node": info.node_name, "type": info.topic_type, "hash": str(info.topic_type_hash)}
            for info in infos if (info.node_name == NAME) == own]


def _moved(odoms: list[Any]) -> float:
    first, last = odoms[0].pose.pose.position, odoms[-1].pose.pose.position
    return float(((last.x - first.x) ** 2 + (last.y - first.y) ** 2) ** 0.5)


def _drive(rclpy: Any, node: Any, twist_type: Any, done: Any, deadline: float) -> int:
    """Publish a forward Twist at 20 Hz until ``done()`` (or the deadline)."""
    pub = node.create_publisher(twist_type, "/cmd_vel", 10)
    message = twist_type()
    message.linear.x = 0.2
    sent = 0
    while not done() and time.monotonic() < deadline:
        pub.publish(message)
        sent += 1
        rclpy.spin_once(node, timeout_sec=0.05)
    return sent


if __name__ == "__main__":
    sys.exit(main())
