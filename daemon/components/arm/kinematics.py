# Forward kinematics of the seed's arm: three joints pitching about y, links up from the mount.
from __future__ import annotations

import math
from dataclasses import dataclass

#: the seed's geometry: where joint1 sits on base_link (x, z, m) and the three link lengths (m)
MOUNT_X, MOUNT_Z = 0.10, 0.18
LINKS = (0.200, 0.410, 0.200)


@dataclass(frozen=True)
class EndEffector:
    """The tool point (the end of link 3, between the fingers) in base_link: x forward, z up
    (m; y is 0, the arm moves in the x-z plane), and the last link's pitch (rad)."""

    x: float
    z: float
    pitch: float

    def to_json(self) -> dict[str, float]:
        return {"x": round(self.x, 4), "y": 0.0, "z": round(self.z, 4),
                "pitch": round(self.pitch, 4)}


def forward(joint1: float, joint2: float, joint3: float) -> EndEffector:
    """Where the tool point is for joint angles (rad). All zero: the links stand straight up
    from the mount; a positive angle turns about +y (right-handed), tipping the arm forward
    (+x). Each joint's angle adds to the ones below it."""
    x, z, pitch = MOUNT_X, MOUNT_Z, 0.0
    for length, angle in zip(LINKS, (joint1, joint2, joint3), strict=True):
        pitch += angle
        x += length * math.sin(pitch)
        z += length * math.cos(pitch)
    return EndEffector(x, z, pitch)


def link_points(joint1: float, joint2: float, joint3: float) -> list[tuple[float, float]]:
    """The mount and the end of each link in base_link (x, z), for a side view."""
    points = [(MOUNT_X, MOUNT_Z)]
    x, z, pitch = MOUNT_X, MOUNT_Z, 0.0
    for length, angle in zip(LINKS, (joint1, joint2, joint3), strict=True):
        pitch += angle
        x, z = x + length * math.sin(pitch), z + length * math.cos(pitch)
        points.append((x, z))
    return points
