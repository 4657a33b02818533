# [navigation]: the costmap, the planner's costs, the path follower's speeds and the goal rules.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option


@dataclass(frozen=True)
class NavigationSettings(SectionSettings, section="navigation"):
    """The [navigation] section, read once (keys with dots as underscores)."""

    enabled: bool = option(True, "accept goals and paths (/goal_pose, POST /api/goal); needs "
                           "[lidar]")
    resolution: float = option(0.1, "cell size of the costmap, m", minval=0.02, maxval=0.5)
    size_m: float = option(40.0, "side of the square costmap centred on where odometry started, "
                           "m; goals outside it are refused", minval=4.0, maxval=200.0)
    plan_block: int = option(2, "the planner searches blocks of this many x this many cells (each "
                             "as dear as its dearest cell), then straightens the path on the cells",
                             minval=1, maxval=8)
    clearance_m: float = option(0.05, "cells nearer an obstacle than the footprint's reach plus "
                                "this are never planned through, m", minval=0.0, maxval=1.0)
    inflation_m: float = option(0.5, "beyond that, cells this close to obstacles cost more (the "
                                "path keeps to the middle), m", minval=0.0, maxval=3.0)
    unknown_cost: float = option(1.0, "extra cost of crossing an unseen cell (1 = a free metre "
                                 "costs double there); unseen space may be planned through",
                                 minval=0.0, maxval=100.0)
    max_speed: float = option(0.5, "top speed along the path, m/s (and at most [limits])",
                              above=0.0, maxval=5.0)
    max_turn: float = option(1.5, "top turning rate, rad/s (and at most [limits])", above=0.0,
                             maxval=10.0)
    xy_tolerance: float = option(0.05, "the goal is reached this close to it, m", minval=0.01,
                                 maxval=2.0)
    yaw_tolerance: float = option(0.05, "and facing its heading within this, rad", minval=0.01,
                                  maxval=3.2)
    control_rate: float = option(20.0, "path-following decisions per second", minval=2.0,
                                 maxval=100.0)
    replan_period_s: float = option(1.0, "replan this often while following (new scans, new "
                                    "obstacles), s", minval=0.1, maxval=30.0)
    progress_timeout_s: float = option(20.0, "no progress toward the goal for this long starts "
                                       "the recoveries, s", minval=2.0, maxval=600.0)
    held_timeout_s: float = option(2.0, "the collision monitor holding the robot this long starts "
                                   "the recoveries, s", minval=0.5, maxval=60.0)
    goal_timeout_s: float = option(30.0, "a goal fails after this long plus 2.5 x the first "
                                   "plan's length at max_speed, s", minval=5.0, maxval=3600.0)
