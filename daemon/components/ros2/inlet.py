# The DDS reader thread: waits on a waitset for incoming samples and lost publishers.
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from daemon.components.ros2.dds import DdsNode

log = logging.getLogger("arbiterd.ros2")

#: how many samples one take hands over at most
TAKE = 32


class Inlet:
    """One thread that sleeps in Cyclone's waitset (the GIL released) until a reader holds
    samples or the publishers of a watched reader change, then takes them and calls
    ``on_samples(key, samples)``, or ``on_unmatched(key)`` when a watched reader's last
    publisher went away. No DDS thread runs Python."""

    def __init__(self, node: DdsNode, on_samples: Callable[[Any, list[bytes]], None],
                 on_unmatched: Callable[[Any], None], wait_s: float = 0.25,
                 min_period_s: float = 0.005) -> None:
        self._node = node
        self._min_period_s = min_period_s
        self._on_samples = on_samples
        self._on_unmatched = on_unmatched
        self._wait_s = wait_s
        self._readers: list[tuple[Any, Any]] = []
        self._watched: dict[Any, list[Any]] = {}  # key -> [reader, publishers last seen]
        self._waitset: Any = None
        self._stop = False
        self.failed = 0
        self._thread = threading.Thread(target=self._run, name="ros2-dds-reader", daemon=True)

    def add(self, key: Any, reader: Any, watch_publishers: bool) -> None:
        """Take from ``reader`` (before :meth:`start`); with ``watch_publishers``, report when
        its last publisher goes."""
        self._readers.append((key, reader))
        if watch_publishers:
            self._watched[key] = [reader, 0]

    def start(self) -> None:
        self._waitset = self._node.waitset([r for _, r in self._readers],
                                           [w[0] for w in self._watched.values()])
        self._thread.start()

    def close(self, timeout_s: float = 2.0) -> None:
        self._stop = True
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def _run(self) -> None:
        """Wake at most once every ``min_period_s``: under a flood the thread sleeps (the GIL
        and the core free for the event loop) while Cyclone keeps each reader's newest."""
        last = 0.0
        while not self._stop:
            try:
                pause = last + self._min_period_s - time.monotonic()
                if pause > 0:
                    time.sleep(pause)
                self._node.wait(self._waitset, self._wait_s)
                last = time.monotonic()
                self._take_all()
                self._check_publishers()
            except Exception as exc:  # a DDS error must not end the thread
                self.failed += 1
                if self.failed <= 3 or self.failed % 1000 == 0:
                    log.warning("ros2: a DDS read failed (%d so far): %r", self.failed, exc)

    def _take_all(self) -> None:
        node = self._node
        for key, reader in self._readers:
            samples = [data for data, _ in node.take_raw(reader, TAKE)]
            if samples:
                self._on_samples(key, samples)

    def _check_publishers(self) -> None:
        for key, seen in self._watched.items():
            now = self._node.subscription_matches(seen[0])
            if now == 0 and seen[1] > 0:
                self._on_unmatched(key)
            seen[1] = now
