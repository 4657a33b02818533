# Motion control: command parsing, arbitration, limits, kinematics, odometry, the control loop.
from __future__ import annotations
