# Repeated log lines throttled per source: a flood of goals or bad requests cannot fill the journal.
from __future__ import annotations

import logging
import time
from collections import OrderedDict
from collections.abc import Callable

#: lines of one kind (logger, level, message template) written per window; the rest counted
BURST = 20
WINDOW_S = 10.0
#: kinds remembered at once (the least recently seen is forgotten first)
MAX_KINDS = 1024


class RepeatFilter(logging.Filter):
    """A handler filter: at most ``burst`` lines of one kind per ``window_s`` pass; the first
    line of the next window says how many were left out. A kind is the logger's name, the
    level and the message *template* (``"goal %d: %s"``), so a thousand different goals
    count as one kind and different messages never hide each other."""

    def __init__(self, burst: int = BURST, window_s: float = WINDOW_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.burst, self.window_s, self.clock = burst, window_s, clock
        #: kind -> [window start, lines passed in it, lines left out in it]
        self._kinds: OrderedDict[tuple[str, int, str], list[float]] = OrderedDict()
        self.suppressed = 0

    def filter(self, record: logging.LogRecord) -> bool:
        kind = (record.name, record.levelno, str(record.msg))
        now = self.clock()
        state = self._kinds.get(kind)
        if state is None or now - state[0] >= self.window_s:
            left_out = int(state[2]) if state is not None else 0
            self._kinds[kind] = [now, 1, 0]
            self._kinds.move_to_end(kind)
            while len(self._kinds) > MAX_KINDS:
                self._kinds.popitem(last=False)
            if left_out:
                _say_left_out(record, left_out, now - (state[0] if state else now))
            return True
        if state[1] < self.burst:
            state[1] += 1
            return True
        state[2] += 1
        self.suppressed += 1
        return False


def _say_left_out(record: logging.LogRecord, count: int, seconds: float) -> None:
    """Append to ``record`` how many lines like it were not logged (once formatted)."""
    text = record.getMessage()
    record.msg, record.args = (f"{text} [{count} more like this not logged in the last "
                               f"{seconds:.0f} s]"), None
