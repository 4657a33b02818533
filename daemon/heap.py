# The garbage collector and the control tick: the heap built at start-up is frozen.
from __future__ import annotations

import gc
import logging
import time

log = logging.getLogger("arbiterd")


def collect_before_start() -> None:
    """One full collection while nothing runs yet: the control tick and its stall supervisor
    start later, so this pause (35-70 ms here, several times that on a Pi or in a long test
    process) cannot look like a stalled loop."""
    start = time.perf_counter()
    gc.collect()
    log.debug("start-up garbage collected (%.0f ms)", (time.perf_counter() - start) * 1e3)


def freeze_startup_heap() -> int:
    """Move every object alive now into the permanent generation; how many were frozen.

    What start-up builds (modules, numpy, aiohttp, the config, the components: ~60 000 objects)
    lives as long as the process, yet every full collection used to walk all of it: 35-70 ms
    with the event loop and the control tick stopped, now and then (a stall stop at 200 ms
    under load). Frozen, a full collection walks only what was made since (a few ms). The
    freeze itself does not walk the heap. Call it once, when start-up is over, after
    :func:`collect_before_start`."""
    gc.freeze()
    return gc.get_freeze_count()


def thaw() -> None:
    """Give the frozen objects back to the collector (the daemon stopped: what it built may
    now be garbage in cycles, which only a collection frees; tests start many daemons)."""
    gc.unfreeze()
