# The DDS layer alone (no rclpy): a writer thread and a reader thread beside another participant.
from __future__ import annotations

import subprocess
import sys
import threading
import time
from typing import Any

from daemon.components.ros2 import announce
from daemon.components.ros2.dds import ANNOUNCE_QOS, DdsNode, announcement_type
from daemon.components.ros2.inlet import Inlet
from tests.support.paths import REPO
from tests.support.wait import wait_for

DOMAIN = 43
WRITE_S = 4.0

#: another participant (another process) writing announcements for ``argv[1]`` seconds
OTHER = f"""
import sys, time
from daemon.components.ros2 import announce
from daemon.components.ros2.dds import ANNOUNCE_QOS, DdsNode, announcement_type
node = DdsNode({DOMAIN}, True, False)
writer = node.writer(announce.TOPIC, announcement_type(16), ANNOUNCE_QOS)
data = announce.encode(node.guid, [announce.NodeInfo("/", "other")], 16)
print("up", flush=True)
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    node.write(writer, data)
node.close()
"""


def test_writing_to_a_topic_this_node_also_reads_never_deadlocks() -> None:
    """The daemon's writer thread writes its announcement, which its own reader of the topic
    receives, while another participant's announcements arrive. With a Python listener on
    that reader this deadlocked: Cyclone's thread sat in the listener waiting for the GIL, and
    the writer, holding the GIL, waited for the listener to end (the daemon hung at start)."""
    node = DdsNode(DOMAIN, True, False)
    info = announcement_type(16)
    writer = node.writer(announce.TOPIC, info, ANNOUNCE_QOS)
    reader = node.reader(announce.TOPIC, info, ANNOUNCE_QOS)
    received: list[bytes] = []
    inlet = Inlet(node, lambda key, samples: received.extend(samples), lambda key: None)
    inlet.add("announcements", reader, watch_publishers=False)
    inlet.start()
    other = subprocess.Popen([sys.executable, "-c", OTHER, str(WRITE_S)], cwd=REPO,
                             stdout=subprocess.PIPE, text=True)
    try:
        assert other.stdout is not None and other.stdout.readline().strip() == "up"
        own = announce.encode(node.guid, [announce.NodeInfo("/", "own")], 16)
        writes = _write_for(node, writer, own, WRITE_S)
        assert writes > 100
        wait_for(lambda: _from(received, "other") and _from(received, "own"),
                 "announcements of both participants taken by the reader thread", within_s=10)
    finally:
        inlet.close()
        other.wait(30)
        node.close()
    assert other.returncode == 0


def _write_for(node: DdsNode, writer: Any, data: bytes, seconds: float) -> int:
    """Writes from a thread of its own for ``seconds``; fails if it does not finish."""
    count = [0]

    def write() -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            node.write(writer, data)
            count[0] += 1

    thread = threading.Thread(target=write, daemon=True)
    thread.start()
    thread.join(seconds + 20)
    assert not thread.is_alive(), f"the writer hung after {count[0]} writes"
    return count[0]


def _from(samples: list[bytes], name: str) -> bool:
    return any(name.encode() in sample for sample in samples)
