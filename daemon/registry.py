# The component table: every component the daemon assembles, in start order (stopped in reverse).
from __future__ import annotations

from daemon.component import ComponentSpec
from daemon.components.arm import component as arm
from daemon.components.autonomy import component as autonomy
from daemon.components.battery import component as battery
from daemon.components.camera import component as camera
from daemon.components.collision_monitor import component as collision_monitor
from daemon.components.console import component as console
from daemon.components.control import component as control
from daemon.components.core import component as core
from daemon.components.dock import component as dock
from daemon.components.fetch import component as fetch
from daemon.components.fleet import component as fleet
from daemon.components.foxglove import component as foxglove
from daemon.components.http import component as http
from daemon.components.lidar import component as lidar
from daemon.components.mapping import component as mapping
from daemon.components.navigation import component as navigation
from daemon.components.recorder import component as recorder
from daemon.components.ros2 import component as ros2
from daemon.components.rosbridge import component as rosbridge
from daemon.components.sim import component as sim

#: Adding a component is one line here (docs/adding-a-component.md): each row is the
#: ``COMPONENT`` of ``daemon/components/<name>/component.py``, whose config section is
#: ``[<name>]``. The HTTP server is last so that it starts when everything it serves is
#: running and stops first.
COMPONENTS: tuple[ComponentSpec, ...] = (
    sim.COMPONENT,
    control.COMPONENT,
    lidar.COMPONENT,
    collision_monitor.COMPONENT,
    autonomy.COMPONENT,
    mapping.COMPONENT,
    navigation.COMPONENT,
    arm.COMPONENT,
    fetch.COMPONENT,
    battery.COMPONENT,
    dock.COMPONENT,
    camera.COMPONENT,
    rosbridge.COMPONENT,
    foxglove.COMPONENT,
    recorder.COMPONENT,
    ros2.COMPONENT,
    fleet.COMPONENT,
    console.COMPONENT,
    core.COMPONENT,
    http.COMPONENT,
)
