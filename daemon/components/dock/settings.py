# [dock]: the charging dock's shape, the way home, contact, and when to go by itself.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option


@dataclass(frozen=True)
class DockSettings(SectionSettings, section="dock"):
    """The [dock] section."""

    enabled: bool = option(True, "a charging dock: POST /api/dock sets where it is, POST "
                           "/api/dock/go goes home; needs [navigation] (and so [lidar])")
    file: str = option("", "where the dock's pose is kept across restarts; \"\" = dock.json in "
                       "the state directory")
    arm_m: float = option(0.30, "the dock's V: each arm's length, m", minval=0.05, maxval=2.0)
    opening_deg: float = option(120.0, "the dock's V: the angle between its arms, deg",
                                minval=30.0, maxval=170.0)
    clearance_m: float = option(0.03, "docked, the footprint stands this far from each arm, m",
                                minval=0.0, maxval=0.5)
    staging_m: float = option(0.6, "navigation brings the robot this far straight out from the "
                              "docked pose, facing the dock; the rest is the final approach, m",
                              minval=0.2, maxval=3.0)
    approach_speed: float = option(0.10, "the final approach's top speed, m/s", above=0.0,
                                   maxval=0.5)
    search_s: float = option(3.0, "at the staging pose, how long the lidar may take to find "
                                  "the V (and how long it may lose it on the way in), s",
                             above=0.0, maxval=60.0)
    contact_wait_s: float = option(4.0, "stopped on the dock, how long the battery may take to "
                                   "show the charger (the pack no longer discharging), s",
                                   above=0.0, maxval=60.0)
    retries: int = option(2, "approaches tried again (backing out first) when no charge comes",
                          minval=0, maxval=10)
    undock_m: float = option(0.4, "leaving the dock backs out this far, m", minval=0.1,
                             maxval=2.0)
    go_home: bool = option(True, "the power policy: at [battery] low go home when the current "
                           "task ends, at very_low at once")
