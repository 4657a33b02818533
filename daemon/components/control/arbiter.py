# Command arbiter: a priority mux over command sources with per-source timeouts and an e-stop latch.
from __future__ import annotations

from dataclasses import dataclass

from daemon.commands import ZERO, Twist


@dataclass
class SourceState:
    """The latest command of one source and when it arrived (monotonic seconds)."""

    name: str
    priority: int
    timeout_s: float
    twist: Twist = ZERO
    t_recv: float = 0.0
    active: bool = False
    #: the decision following this command (made once per command, not once per step)
    decision: Decision | None = None

    def is_live(self, now: float) -> bool:
        return self.active and (self.timeout_s <= 0 or now - self.t_recv <= self.timeout_s)


@dataclass(frozen=True)
class Decision:
    """What the arbiter wants now: the target, who set it, and whether to brake hard."""

    twist: Twist
    source: str | None
    emergency: bool
    reason: str


IDLE = Decision(ZERO, None, False, "idle")
DEADMAN = Decision(ZERO, None, True, "deadman: no valid command")


class Arbiter:
    """Picks the command to follow: the live source with the highest priority (the newest
    among equals). The e-stop latch overrides everything until released. A source that times
    out or disconnects while it was in charge makes the robot brake with the emergency
    deceleration (the deadman stop); a source commanding zero brakes normally.
    """

    def __init__(self, default_timeout_s: float) -> None:
        self.default_timeout_s = default_timeout_s
        self.sources: dict[str, SourceState] = {}
        self.estop_engaged = False
        self.estop_reason = ""
        #: latched for good (the daemon is shutting down): nothing releases it
        self.estop_final = False
        self._generation = 0
        self._last_source: str | None = None
        self._estop = Decision(ZERO, None, True, "e-stop: ")

    def submit(self, source: str, twist: Twist, now: float, priority: int = 10,
               timeout_s: float | None = None) -> None:
        state = self.sources.get(source)
        if state is None:
            state = SourceState(source, priority,
                                self.default_timeout_s if timeout_s is None else timeout_s)
            self.sources[source] = state
        state.priority = priority
        state.twist, state.t_recv, state.active, state.decision = twist, now, True, None

    def drop(self, source: str) -> None:
        """Forget a source (its client disconnected)."""
        self.sources.pop(source, None)

    def invalidate_all(self) -> None:
        """Require a fresh command from every source (after a fault or an e-stop release)."""
        for state in self.sources.values():
            state.active = False

    def engage_estop(self, reason: str, *, final: bool = False) -> None:
        """Latch the e-stop; ``final`` (shutdown): for good, :meth:`release_estop` refuses."""
        if not self.estop_final:
            self.estop_reason = reason
        self.estop_engaged = True
        self.estop_final = self.estop_final or final
        self._estop = Decision(ZERO, None, True, f"e-stop: {self.estop_reason}")
        self.invalidate_all()

    def release_estop(self) -> bool:
        """Release the e-stop; False (still engaged) when it was latched for good."""
        if self.estop_final:
            return False
        self.estop_engaged, self.estop_reason = False, ""
        self.invalidate_all()
        return True

    def decide(self, now: float) -> Decision:
        if self.estop_engaged:
            return self._estop
        best: SourceState | None = None
        for state in self.sources.values():  # the first of the highest (priority, t_recv)
            if state.is_live(now) and (best is None or (state.priority, state.t_recv)
                                       > (best.priority, best.t_recv)):
                best = state
        if best is None:
            return IDLE if self._last_source is None else DEADMAN
        self._last_source = best.name
        if best.decision is None:
            best.decision = Decision(best.twist, best.name, False, "command")
        return best.decision

    def idle(self) -> None:
        """The robot has stopped after a deadman brake: later silence is plain idling."""
        self._last_source = None
