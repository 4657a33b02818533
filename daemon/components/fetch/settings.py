# [fetch]: the fetch behaviour's switch and how it approaches an object or a drop point.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import Option, Options

FETCH_OPTIONS: Options = {
    "enabled": Option(bool, True, "accept fetch missions (POST /api/fetch); needs [arm] and "
                      "[navigation] (and so [lidar])"),
    "approaches": Option(int, 3, "standoff poses tried in turn around the object (and the "
                         "drop point) when navigation cannot reach one", minval=1, maxval=16),
    "object_clearance_m": Option(float, 0.3, "an object or drop point with a seen obstacle "
                                 "nearer than this (beyond the object itself) is refused, m",
                                 minval=0.1, maxval=2.0),
}


@dataclass(frozen=True)
class FetchSettings(SectionSettings, section="fetch", options=FETCH_OPTIONS):
    enabled: bool
    approaches: int
    object_clearance_m: float
