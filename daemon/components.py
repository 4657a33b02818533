# The component table: every part the daemon assembles, in start order (stopped in reverse).
from __future__ import annotations

from daemon import console, core_api, http_api, lidar, simulator
from daemon.arm import component as arm
from daemon.autonomy import component as autonomy
from daemon.component import ComponentSpec
from daemon.control import api as control
from daemon.fetch import component as fetch
from daemon.mapping import component as mapping
from daemon.navigation import component as navigation
from daemon.recorder import component as recorder
from daemon.ros2 import component as ros2
from daemon.rosbridge import server as rosbridge
from daemon.safety import component as collision_monitor

#: Adding a component is one line here (docs/adding-a-component.md). Each row names the
#: config section it owns; the HTTP server is last so that it starts when everything it
#: serves is running and stops first.
COMPONENTS: tuple[ComponentSpec, ...] = (
    simulator.COMPONENT,
    control.COMPONENT,
    lidar.COMPONENT,
    collision_monitor.COMPONENT,
    autonomy.COMPONENT,
    mapping.COMPONENT,
    navigation.COMPONENT,
    arm.COMPONENT,
    fetch.COMPONENT,
    rosbridge.COMPONENT,
    recorder.COMPONENT,
    ros2.COMPONENT,
    console.COMPONENT,
    core_api.COMPONENT,
    http_api.COMPONENT,
)
