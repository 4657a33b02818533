# One worker process for a component's numerical work (the mapper, navigation's planner), so
# its CPU time never holds the interpreter lock the control tick needs.
from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any


def worker_pool(initializer: Callable[..., None], *initargs: Any) -> ProcessPoolExecutor:
    """A pool of one fresh (spawned) process, set up by ``initializer(*initargs)``; calls are
    answered in order. The process ends with the daemon, however the daemon ended."""
    return ProcessPoolExecutor(
        max_workers=1, mp_context=multiprocessing.get_context("spawn"),
        initializer=_start, initargs=(os.getpid(), initializer, initargs))


def _start(parent: int, initializer: Callable[..., None], initargs: tuple[Any, ...]) -> None:
    threading.Thread(target=_exit_with_parent, args=(parent,), name="parent-watch",
                     daemon=True).start()
    initializer(*initargs)


def _exit_with_parent(parent: int, every_s: float = 0.5) -> None:
    """End the worker once its daemon is gone (SIGKILL included): no orphan keeps a core busy."""
    while os.getppid() == parent:
        time.sleep(every_s)
    os._exit(0)
