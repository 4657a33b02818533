# Worker processes for a component's numerical work (the mapper, the planner), restarted when
# they die; their CPU time never holds the interpreter lock the control tick needs.
from __future__ import annotations

import asyncio
import logging
import multiprocessing
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from daemon.health import Status

T = TypeVar("T")
log = logging.getLogger("arbiterd.workers")


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


#: a restarted worker must answer within this long (s), else the restart failed
START_TIMEOUT_S = 30.0
#: how often a worker is looked at between jobs (s): a death is noticed within this
WATCH_PERIOD_S = 0.5


class WorkerDown(RuntimeError):
    """A job refused or lost because its worker process is down (being restarted)."""


class SupervisedWorker:
    """A :func:`worker_pool` that is restarted with back-off when its process dies (a kill,
    the OOM killer): ``backoff_s`` (first, longest) between attempts. A job in flight then,
    and every job while it is down, fails with :class:`WorkerDown` saying so; :meth:`problem`
    is what its component's health reports meanwhile: ``degraded`` while restarting,
    ``error`` once ``error_after`` restarts in a row failed. ``initargs`` is called for each
    start: a restart may begin from the latest state (the pose the mapper last had)."""

    def __init__(self, name: str, initializer: Callable[..., None],
                 initargs: Callable[[], tuple[Any, ...]], *,
                 backoff_s: tuple[float, float] = (0.5, 30.0), error_after: int = 3) -> None:
        self.name = name
        self.initializer, self.initargs = initializer, initargs
        self.backoff_s, self.error_after = backoff_s, error_after
        self.pool: ProcessPoolExecutor | None = worker_pool(initializer, *initargs())
        #: why it is down ("" while it is up), restarts done, and failed in a row
        self.down = ""
        self.restarts = 0
        self.failed_starts = 0
        self._tasks: set[asyncio.Task[Any]] = set()
        self._closed = False

    async def call(self, function: Callable[..., T], *args: Any) -> T:
        """``function(*args)`` in the worker; :class:`WorkerDown` when it is down or dies."""
        self._watch_started()
        pool = self.pool
        if pool is None or self.down:
            raise WorkerDown(f"the {self.name} worker is down ({self.down}); it is being "
                             "restarted")
        try:
            return await asyncio.get_running_loop().run_in_executor(pool, function, *args)
        except BrokenProcessPool:
            self._died(pool)
            raise WorkerDown(f"the {self.name} worker died during the job (killed, or out of "
                             "memory); it is being restarted") from None

    def problem(self) -> tuple[Status, str] | None:
        """(``degraded`` or ``error``, why) while the worker is down, else None."""
        pool = self.pool
        if pool is not None and _broken(pool):
            self._died(pool)
        if not self.down:
            return None
        status: Status = "error" if self.failed_starts >= self.error_after else "degraded"
        return status, f"the {self.name} worker is down: {self.down}"

    def values(self) -> dict[str, Any]:
        return {"up": not self.down, "restarts": self.restarts}

    def _watch_started(self) -> None:
        if not self._tasks and not self._closed:
            self._spawn(self._watch())

    def _spawn(self, coroutine: Any) -> None:
        task = asyncio.get_running_loop().create_task(coroutine)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _watch(self) -> None:
        """Notice a death between jobs (nobody asked it anything) and restart it."""
        while not self._closed:
            await asyncio.sleep(WATCH_PERIOD_S)
            pool = self.pool
            if pool is not None and _broken(pool):
                self._died(pool)

    def _died(self, pool: ProcessPoolExecutor) -> None:
        if pool is not self.pool or self._closed:
            return  # noticed already
        self.pool, self.down = None, "its process died (killed, or out of memory); restarting"
        log.error("the %s worker process died; restarting it", self.name)
        pool.shutdown(wait=False, cancel_futures=True)
        self._spawn(self._restart())

    async def _restart(self) -> None:
        delay, longest = self.backoff_s
        while not self._closed:
            await asyncio.sleep(delay)
            pool = worker_pool(self.initializer, *self.initargs())
            try:
                async with asyncio.timeout(START_TIMEOUT_S):
                    await asyncio.get_running_loop().run_in_executor(pool, _alive)
            except Exception as exc:  # it died again, or hung in its start-up
                pool.shutdown(wait=False, cancel_futures=True)
                self.failed_starts += 1
                self.down = (f"{self.failed_starts} restarts failed, the last: "
                             f"{type(exc).__name__}; retrying in {min(2 * delay, longest):g} s")
                log.error("the %s worker did not restart: %r", self.name, exc)
                delay = min(2 * delay, longest)
                continue
            self.pool, self.down, self.failed_starts = pool, "", 0
            self.restarts += 1
            log.warning("the %s worker was restarted (restart %d)", self.name, self.restarts)
            return

    def close(self) -> None:
        """Stop restarting and end the worker (waits for it)."""
        self._closed = True
        for task in list(self._tasks):
            task.cancel()
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)


def _alive() -> bool:
    return True


def _broken(pool: ProcessPoolExecutor) -> bool:
    """The executor found a process of its own dead (CPython sets ``_broken`` then)."""
    return bool(getattr(pool, "_broken", False))
