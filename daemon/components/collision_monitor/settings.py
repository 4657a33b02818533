# [collision_monitor]: footprint, zones and timing of the collision monitor.
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from base.config import SectionSettings
from base.options import option


def _footprint_check(value: list[Any]) -> str | None:
    """``[]`` or ``[[x, y], ...]`` with at least 3 corners (each item is checked alone too)."""
    if value and all(isinstance(item, list) for item in value):
        if len(value) < 3:
            return f"a polygon needs at least 3 [x, y] corners, got {len(value)}"
        return None
    if len(value) != 2 or not all(isinstance(v, int | float) and not isinstance(v, bool)
                                  and math.isfinite(v) for v in value):
        return f"expected a corner [x, y] of two finite numbers, got {value!r}"
    return None


@dataclass(frozen=True)
class CollisionMonitorSettings(SectionSettings, section="collision_monitor"):
    """The [collision_monitor] section, read once (keys with dots as underscores)."""

    enabled: bool = option(True, "keep the robot out of what the lidar sees (acts only when "
                           "[lidar] is enabled; false disables it, with a warning)")
    footprint_radius: float = option(0.2, "radius of the robot's round footprint, m (used when "
                                     "footprint is empty)", above=0.0, maxval=5.0)
    footprint: list[Any] = option([], "polygon footprint [[x, y], ...] in the robot frame, m (x "
                                  "forward, y left; the origin inside); [] = the round footprint",
                                  item=list, check=_footprint_check)
    stop_margin_m: float = option(0.10, "stop zone: obstacles this close to the footprint stop "
                                  "any motion toward them, m", minval=0.0, maxval=2.0)
    slowdown_margin_m: float = option(0.35, "slowdown zone: obstacles this close to the footprint "
                                      "slow motion toward them, m", minval=0.0, maxval=5.0)
    slowdown_ratio: float = option(0.5, "speed factor in the slowdown zone", above=0.0, maxval=1.0)
    time_before_collision_s: float = option(1.0, "approach: project the commanded motion this far "
                                            "ahead and limit speed so the robot can stop before "
                                            "the stop zone", above=0.0, maxval=10.0)
    reaction_time_s: float = option(0.3, "approach: delay from a lower target to the wheels "
                                    "following it (the motors' time constant plus the driver's "
                                    "latency and a margin; `arbiterd test-motors` measures it), "
                                    "s; [control] stall_stop_s is added (one control period "
                                    "without the stall supervisor)", minval=0.0, maxval=2.0)
    min_points: int = option(1, "lidar points needed inside a zone before it counts (noise filter)",
                             minval=1, maxval=100)
    source_timeout_s: float = option(0.5, "a scan older than this is stale: stale_action applies, "
                                     "it never counts as no obstacle", above=0.0, maxval=10.0)
    stale_action: str = option("stop", "what a stale or missing scan does: stop, or slowdown "
                               "(slowdown_ratio, still limited by the last scan)",
                               choices=("stop", "slowdown"))
