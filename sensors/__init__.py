# Sensors of arbiterd: the RPLIDAR stack and the LaserScan type.
from __future__ import annotations
