# Off the control tick: latest-value slots and a bounded event queue, sent by one thread.
from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

log = logging.getLogger("arbiterd.fleet")

#: how often the sender thread looks at the slots, s (the fastest rate it can keep)
WAKE_S = 0.1
_NOTHING = object()


@dataclass
class Channel:
    """One key the robot publishes: at most once per ``period_s``, and again every
    ``refresh_s`` unchanged (0: never). ``encode`` turns a bus message into the payload."""

    key: str
    encoding: str
    encode: Callable[[Any], bytes]
    period_s: float
    refresh_s: float = 0.0
    latest: Any = _NOTHING
    fresh: bool = False
    sent_at: float = -1e9
    sent: int = 0
    sent_bytes: int = 0
    errors: int = 0
    events: deque[Any] | None = field(default=None)

    @property
    def has_latest(self) -> bool:
        return self.latest is not _NOTHING


Send = Callable[[str, bytes, str], None]


class Outbox:
    """What the robot publishes, decoupled from who produces it: :meth:`offer` (from the
    control tick) only stores the newest message, :meth:`event` appends to a bounded queue
    (the oldest dropped); the sender thread encodes and sends at each channel's rate. Nothing
    is sent while ``send`` is None (no session yet)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self.channels: dict[str, Channel] = {}
        self.send: Send | None = None
        self.dropped = 0
        self._wake = threading.Event()
        self._closed = False
        self._thread: threading.Thread | None = None

    def add(self, name: str, channel: Channel) -> Callable[[Any], None]:
        """The channel, and the bus callback that feeds it (O(1))."""
        self.channels[name] = channel
        if channel.events is not None:
            return lambda message: self.event(channel, message)

        def offer(message: Any) -> None:
            channel.latest = message
            channel.fresh = True

        return offer

    def event(self, channel: Channel, message: Any) -> None:
        assert channel.events is not None
        if len(channel.events) == channel.events.maxlen:
            self.dropped += 1
        channel.events.append(message)
        self._wake.set()

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="fleet-outbox", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._closed = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def _run(self) -> None:
        while not self._closed:
            self._wake.wait(WAKE_S)
            self._wake.clear()
            send = self.send
            if send is not None:
                self.flush(send, self.clock())

    def flush(self, send: Send, now: float) -> None:
        """Send what is due (the sender thread; tests call it directly)."""
        for channel in self.channels.values():
            if channel.events is not None:
                while channel.events:
                    self._send(send, channel, channel.events.popleft(), now)
                continue
            if channel.latest is _NOTHING or now - channel.sent_at < channel.period_s:
                continue
            due_refresh = channel.refresh_s > 0 and now - channel.sent_at >= channel.refresh_s
            if channel.fresh or due_refresh:
                channel.fresh = False
                self._send(send, channel, channel.latest, now)

    @staticmethod
    def _send(send: Send, channel: Channel, message: Any, now: float) -> None:
        try:
            payload = channel.encode(message)
            send(channel.key, payload, channel.encoding)
        except Exception as exc:  # one bad message or a closed session stops nothing else
            channel.errors += 1
            if channel.errors == 1:
                log.warning("fleet: %s not sent: %s", channel.key, exc)
            return
        channel.sent_at = now
        channel.sent += 1
        channel.sent_bytes += len(payload)
