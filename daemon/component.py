# The component contract: what every part of the running daemon declares, and what it is given.
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, runtime_checkable

from base.config import Config, SectionSettings
from daemon.bus import Bus, BusKey
from daemon.health import Health
from daemon.hooks import HookMap, Remove
from daemon.latency import LatencyTracker
from daemon.listen import Listener
from daemon.robot import RobotBase, TickHooks
from daemon.security import Security
from daemon.topics import Access, Topic, TopicTable
from daemon.web import HttpPort
from sensors.scan import ScanPoints
from sim.stepper import SimWorld

if TYPE_CHECKING:
    from aiohttp import web

T = TypeVar("T")
S = TypeVar("S", bound=SectionSettings)

Handler = Callable[["web.Request"], Any]


@dataclass(frozen=True)
class Route:
    """An HTTP route a component serves, with who may call it (one middleware enforces it)."""

    method: str
    path: str
    handler: Handler
    access: Access


@runtime_checkable
class Component(Protocol):
    """A part of the daemon with a lifecycle, a health report and what it declares.

    ``core`` components must start for the daemon to become ready (``READY=1``); a failing
    non-core component only degrades health. ``health()`` returns a :class:`Health` (status,
    the one problem, values), or None for a component with nothing to report. ``routes()``
    and ``topics()`` are read once, after it is built.
    """

    name: str
    core: bool

    async def start(self) -> None: ...

    async def stop(self) -> None: ...

    def health(self) -> Health | None: ...

    def routes(self) -> Sequence[Route]: ...

    def topics(self) -> Sequence[Topic]: ...


class BaseComponent:
    """Defaults for the optional parts of :class:`Component`: nothing to start, stop, serve or
    publish, and an ``ok`` health."""

    name: str = ""
    core: bool = False

    async def start(self) -> None:
        return None

    async def stop(self) -> None:
        return None

    def health(self) -> Health | None:
        return Health("ok")

    def routes(self) -> Sequence[Route]:
        return ()

    def topics(self) -> Sequence[Topic]:
        return ()


class Reports(Protocol):
    """The daemon's own reports, for the component that serves them."""

    def health(self) -> dict[str, Any]: ...

    def robot_info(self) -> dict[str, Any]: ...


class Plugs:
    """Registrations into the control loop and the bus, each remembered so that
    :meth:`release` takes them all out (newest first). The daemon gives every component its
    own; so does the lockstep simulator, which builds components without the rest."""

    def __init__(self, hooks: TickHooks, robot: RobotBase, bus: Bus) -> None:
        self.hooks = hooks
        self.robot = robot
        self.bus = bus
        self._undo: list[Remove] = []

    def release(self) -> None:
        while self._undo:
            self._undo.pop()()

    def _keep(self, remove: Remove) -> Remove:
        self._undo.append(remove)
        return remove

    def subscribe(self, key: BusKey[T], callback: Callable[[T], None]) -> Remove:
        return self._keep(self.bus.subscribe(key, callback))

    def on_tick(self, callback: Callable[[float, bool], None]) -> Remove:
        """``callback(now, on_time)`` after every control tick."""
        return self._keep(self.hooks.on_tick.add(callback))

    def schedule(self, callback: Callable[[float], float]) -> Remove:
        """``callback(now)`` from the first control tick, then from the first tick at or after
        the time it returns (periodic work that costs an idle tick nothing in between)."""
        return self._keep(self.hooks.schedule.add(callback))

    def add_tick_source(self, callback: Callable[[float], None]) -> Remove:
        """``callback(now)`` at the start of every tick, before the step (internal sources)."""
        return self._keep(self.hooks.tick_sources.add(callback))

    def on_command(self, callback: Callable[[str], None]) -> Remove:
        """``callback(source)`` after every accepted command from a source."""
        return self._keep(self.hooks.on_command.add(callback))

    def add_status(self, name: str, supplier: Callable[[], Any]) -> Remove:
        """A field of ``/api/status``."""
        return self._keep(self.hooks.status_fields.add(name, supplier))

    def add(self, remove: Remove) -> Remove:
        """Any other registration's remover, to be called on release."""
        return self._keep(remove)

    def while_busy(self, *, tick_source: Callable[[float], None] | None = None,
                   on_tick: Callable[[float, bool], None] | None = None,
                   on_command: Callable[[str], None] | None = None) -> BusyHooks:
        """Hooks a component needs only while it is busy (see :class:`BusyHooks`)."""
        hooks = BusyHooks(self.hooks, tick_source, on_tick, on_command)
        self._keep(hooks.stop)
        return hooks


class BusyHooks:
    """A component's tick and command hooks while it is busy (a goal, a fetch, a mode):
    :meth:`start` puts them in, :meth:`stop` takes them out, so an idle component costs the
    control tick and every command nothing. A hook that finds nothing to do may call
    :meth:`stop` itself (no end of the work has to be caught where it happens)."""

    def __init__(self, hooks: TickHooks, tick_source: Callable[[float], None] | None,
                 on_tick: Callable[[float, bool], None] | None,
                 on_command: Callable[[str], None] | None) -> None:
        self._tick_hooks = hooks
        self._hooks = (tick_source, on_tick, on_command)
        self._removers: list[Remove] = []

    def start(self) -> None:
        if self._removers:
            return
        control, (tick_source, on_tick, on_command) = self._tick_hooks, self._hooks
        if tick_source is not None:
            self._removers.append(control.tick_sources.add(tick_source))
        if on_tick is not None:
            self._removers.append(control.on_tick.add(on_tick))
        if on_command is not None:
            self._removers.append(control.on_command.add(on_command))

    def stop(self) -> None:
        while self._removers:
            self._removers.pop()()


class SimPort(Protocol):
    """The simulated world of ``run --sim`` as components see it (``ctx.sim``)."""

    @property
    def world(self) -> SimWorld: ...

    @property
    def device_emulators(self) -> dict[str, Any]:
        """The emulator of each emulated device, by the config section that uses it."""
        ...


@dataclass
class DaemonContext:
    """What a component gets to build itself and plug into the daemon.

    ``plugs`` remembers every hook a component registers; the daemon gives each component its
    own :meth:`scoped` copy and releases its plugs after the component stopped, so nothing a
    component hooked in outlives it.
    """

    config: Config
    bus: Bus
    http: HttpPort
    #: the robot base: pose, velocity, commands through the arbiter, e-stop and fault state
    robot: RobotBase
    security: Security
    latency: LatencyTracker
    mode: str
    topics: TopicTable
    #: one scan -> robot-frame points converter for everyone (each revolution converted once)
    scan_points: ScanPoints
    reports: Reports
    plugs: Plugs
    #: the simulated world and emulators (``run --sim``), else None
    sim: SimPort | None = None
    #: extra fields of /api/robot_info and /robot_info, by name
    robot_info: HookMap[Callable[[], Any]] = field(default_factory=HookMap)
    #: the components built so far (earlier rows of the table), by name: a behaviour that
    #: drives other components (the fetch: navigation and the arm) finds them here
    components: dict[str, Component] = field(default_factory=dict)

    def settings(self, settings: type[S]) -> S:
        return self.config.get(settings)

    def scoped(self) -> DaemonContext:
        return dataclasses.replace(self, plugs=Plugs(self.plugs.hooks, self.robot, self.bus))

    def add_robot_info(self, name: str, supplier: Callable[[], Any]) -> Remove:
        return self.plugs.add(self.robot_info.add(name, supplier))



@dataclass(frozen=True)
class DeviceUse:
    """A device (``drivers.device_registry.DEVICES``) a component uses, configured by the keys
    of ``section``. Under ``arbiterd run --sim`` its emulator is started and the options that
    reach it (a port, an address) are written into that section before the component is built."""

    device: str
    section: str


@dataclass(frozen=True)
class ComponentSpec:
    """One row of the component table: a name, the typed settings of the config section it
    owns (None: it reads only the core sections), the factory that builds it from the
    context (None when its section disables it), the devices the configuration makes it
    use, and the TCP ports it listens on (the daemon checks them before anything starts)."""

    name: str
    create: Callable[[DaemonContext], Component | None]
    settings: type[SectionSettings] | None = None
    devices: Callable[[Config], Sequence[DeviceUse]] | None = None
    listens: Callable[[Config], Sequence[Listener]] | None = None

    def devices_used(self, config: Config) -> list[DeviceUse]:
        return list(self.devices(config)) if self.devices is not None else []

    def listeners(self, config: Config) -> list[Listener]:
        return list(self.listens(config)) if self.listens is not None else []
