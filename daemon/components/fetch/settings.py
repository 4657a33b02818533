# [fetch]: the fetch behaviour's switch and how it approaches an object or a drop point.
from __future__ import annotations

from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option


@dataclass(frozen=True)
class FetchSettings(SectionSettings, section="fetch"):
    enabled: bool = option(True, "accept fetch missions (POST /api/fetch); needs [arm] and "
                           "[navigation] (and so [lidar])")
    approaches: int = option(3, "standoff poses tried in turn around the object (and the drop "
                             "point) when navigation cannot reach one", minval=1, maxval=16)
    object_clearance_m: float = option(0.3, "an object or drop point with a seen obstacle nearer "
                                       "than this (beyond the object itself) is refused, m",
                                       minval=0.1, maxval=2.0)
