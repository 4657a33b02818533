# [mapping]: build a map from the lidar (or localise in a saved one), and where maps are kept.
from __future__ import annotations

import re
from dataclasses import dataclass

from base.config import SectionSettings
from base.options import option

#: what a map's name may be: it becomes NAME.yaml and NAME.pgm in the maps directory
MAP_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def map_name_error(name: str) -> str | None:
    """Why ``name`` cannot name a map file, or None."""
    if not MAP_NAME.fullmatch(name) or name.endswith((".yaml", ".pgm")):
        return (f"{name!r} is not a map name: 1-64 letters, digits, '_', '-' or '.', "
                "starting with a letter or digit, without an extension")
    return None


def _map_name_or_empty(name: str) -> str | None:
    return map_name_error(name) if name else None


@dataclass(frozen=True)
class MappingSettings(SectionSettings, section="mapping"):
    """The [mapping] section, read once."""

    enabled: bool = option(False, "build a map from the lidar and track the robot's pose in it "
                           "(needs [lidar])")
    mode: str = option("map", "map: build a new map as the robot drives; localize: track the pose "
                       "in the saved map named by `map`", choices=("map", "localize"))
    map: str = option("", "localize: the saved map's name (arbiterd map list)",
                      check=_map_name_or_empty)
    initial_pose: list[float] = option([0.0, 0.0, 0.0], "localize: the pose to start from, [x m, "
                                       "y m, heading degrees] in the map; /initialpose and POST "
                                       "/api/pose set it later", length=3)
    find_pose: bool = option(True, "localize: find the pose on the whole map by itself at start "
                             "and after POST /api/map/load without a pose (initial_pose is then "
                             "not used); false: start from initial_pose")
    resolution: float = option(0.05, "cell size of the map, m", minval=0.01, maxval=0.5)
    max_range_m: float = option(12.0, "returns farther than this are not put in the map, m",
                                minval=1.0, maxval=40.0)
    max_size_m: float = option(100.0, "the map grows as the robot explores up to this width and "
                               "height, m; what lies beyond is dropped and counted", minval=5.0,
                               maxval=500.0)
    loop_closure: bool = option(True, "map: correct the whole map when the robot comes back to a "
                                "place it has seen")
    publish_period_s: float = option(2.0, "/map is published at most this often, and only when it "
                                     "changed, s", minval=0.2, maxval=60.0)
    directory: str = option("", "where saved maps go; '' = maps/ in the service's state directory "
                            "($STATE_DIRECTORY, /var/lib/arbiterd under systemd), else "
                            "~/.local/state/arbiterd/maps")
    max_saved_mb: float = option(200.0, "saved maps (POST /api/map/save) may fill the maps "
                                 "directory up to this many MB; a save beyond is refused (507)",
                                 minval=1.0, maxval=100000.0)
    map_frame_id: str = option("map", "frame of the map, /pose and the map -> odom transform")

    @property
    def max_cells(self) -> int:
        """The most cells a map may have: built (it grows up to ``max_size_m`` square) or
        loaded (a bigger one is refused from its header, before any work)."""
        return int((self.max_size_m / self.resolution) ** 2)
