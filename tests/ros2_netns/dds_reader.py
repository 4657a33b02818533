# A bare Cyclone DDS reader of rt/scan, with an SROS2 enclave or none: prints how many it took.
"""``python dds_reader.py DOMAIN ENCLAVE|- SECONDS``: samples of sensor_msgs/LaserScan on
rt/scan taken in SECONDS (best effort, loopback discovery as the face's), as ``received N``."""
from __future__ import annotations

import sys
import time

from daemon.components.ros2 import security
from daemon.components.ros2.dds import DdsNode, QosSpec, idl_type, libddsc_path


def main() -> int:
    domain, enclave, seconds = int(sys.argv[1]), sys.argv[2], float(sys.argv[3])
    xml = "" if enclave == "-" else security.cyclone_xml(security.enclave(enclave),
                                                          libddsc_path())
    node = DdsNode(domain, True, True, xml)
    reader = node.reader("rt/scan", idl_type("sensor_msgs/msg/LaserScan"),
                         QosSpec(reliable=False, transient_local=False, depth=10))
    print("up", flush=True)
    received, end = 0, time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(0.05)
        received += len(node.take_raw(reader, 64))
    print(f"received {received}", flush=True)
    node.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
