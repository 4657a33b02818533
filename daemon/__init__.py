# arbiterd: the on-robot daemon of the ArbiterROS platform (no ROS on the robot).
from __future__ import annotations

__version__ = "0.1.0"
