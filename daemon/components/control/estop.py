# Who may latch and release the e-stop, and how often one peer may latch it.
from __future__ import annotations

import time
from collections.abc import Callable

from daemon.topics import Access

#: Anyone who passes the Host and Origin checks may stop the robot (no token); releasing it
#: lets the robot move again, so it needs what driving needs. The one place this is decided:
#: HTTP (POST /api/estop) and rosbridge (/estop) both ask :func:`estop_access`.
LATCH: Access = "stop"
RELEASE: Access = "drive"

LATCH_BURST = 3  # latches one peer may send within LATCH_WINDOW_S
LATCH_WINDOW_S = 1.0
LATCH_PEERS = 256  # peers remembered; the least recently seen one is forgotten first


def estop_access(engaged: bool) -> Access:
    """The access latching (``True``) or releasing (``False``) the e-stop needs."""
    return LATCH if engaged else RELEASE


class LatchLimit:
    """At most ``burst`` latches per ``window_s`` from one peer (its network address).

    O(1) per latch and at most ``peers`` entries: the least recently seen peer is forgotten
    when a new one comes, which only ever lets more through. The caller refuses a latch over
    the limit only while the e-stop is already engaged: a latch that stops the robot is never
    refused; what the limit bounds is the work and the log lines of a peer repeating it.
    """

    def __init__(self, burst: int = LATCH_BURST, window_s: float = LATCH_WINDOW_S,
                 peers: int = LATCH_PEERS, clock: Callable[[], float] = time.monotonic) -> None:
        self.burst = burst
        self.window_s = window_s
        self.peers = peers
        self.clock = clock
        self._seen: dict[str, tuple[float, int]] = {}  # peer -> (window start, latches in it)
        self.limited = 0  # latches over the limit, all peers

    def allow(self, peer: str) -> bool:
        """Count one latch from ``peer``; False when it is over that peer's limit."""
        now = self.clock()
        start, count = self._seen.pop(peer, (now, 0))
        if now - start >= self.window_s:
            start, count = now, 0
        self._seen[peer] = (start, count + 1)  # (re)inserted last: the most recently seen
        if len(self._seen) > self.peers:
            del self._seen[next(iter(self._seen))]
        if count < self.burst:
            return True
        self.limited += 1
        return False

    def __len__(self) -> int:
        return len(self._seen)
