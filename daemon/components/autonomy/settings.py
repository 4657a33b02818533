# [autonomy]: the wander behaviour's speeds, clearances and seed.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option


@dataclass(frozen=True)
class AutonomySettings(SectionSettings, section="autonomy"):
    """The [autonomy] section, read once (keys with dots as underscores)."""

    mode: str = option("off", "behaviour at start: off, wander (drives by itself) or explore "
                       "(frontier exploration: needs [navigation])",
                       choices=("off", "wander", "explore"))
    cruise_speed: float = option(0.6, "wander: forward speed in the open, m/s", above=0.0,
                                 maxval=5.0)
    turn_speed: float = option(1.5, "wander: turning rate in place, rad/s", above=0.0, maxval=10.0)
    clearance_m: float = option(0.25, "wander: distance it keeps from obstacles (beyond the "
                                "collision monitor's footprint), m", minval=0.0, maxval=3.0)
    look_ahead_m: float = option(1.6, "wander: free distance ahead at which it starts avoiding, m",
                                 above=0.0, maxval=10.0)
    decision_rate: float = option(10.0, "decisions per second", minval=1.0, maxval=100.0)
    seed: int = option(0, "seed of the wander heading changes (0 = random)", minval=0)
