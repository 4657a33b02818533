# Registration points other parts plug into; every registration returns its own remover.
from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

F = TypeVar("F")
V = TypeVar("V")

Remove = Callable[[], None]


class HookList(Generic[F]):
    """An ordered list of callbacks; :meth:`add` returns the function that takes it out."""

    def __init__(self) -> None:
        self._items: list[F] = []
        #: the callbacks now, as a tuple: what iteration walks (safe to change meanwhile);
        #: a hot path iterates it directly, without a call to ``__iter__``
        self.snapshot: tuple[F, ...] = ()

    def add(self, item: F) -> Remove:
        self._items.append(item)
        self.snapshot = tuple(self._items)

        def remove() -> None:
            if item in self._items:
                self._items.remove(item)
                self.snapshot = tuple(self._items)

        return remove

    def __iter__(self) -> Iterator[F]:
        return iter(self.snapshot)

    def __len__(self) -> int:
        return len(self._items)


class Schedule:
    """Callbacks run from the control tick when due: each is called with the tick's time and
    returns when it is due next. A tick with nothing due costs one comparison
    (``now >= schedule.next_due``); an idle robot's periodic reports need no hook a tick."""

    def __init__(self) -> None:
        self._due: dict[Callable[[float], float], float] = {}
        #: the earliest time any callback is due
        self.next_due = math.inf

    def add(self, callback: Callable[[float], float]) -> Remove:
        """Run ``callback`` at the next tick, then when it says."""
        self._due[callback] = self.next_due = -math.inf

        def remove() -> None:
            self._due.pop(callback, None)
            self.next_due = min(self._due.values(), default=math.inf)

        return remove

    def run(self, now: float) -> None:
        """Call every callback due at ``now`` (one that raises is due again a second later)."""
        due = self._due
        try:
            for callback, at in list(due.items()):
                if at <= now and callback in due:
                    due[callback] = now + 1.0
                    due[callback] = callback(now)
        finally:
            self.next_due = min(due.values(), default=math.inf)

    def __len__(self) -> int:
        return len(self._due)


class HookMap(Generic[V]):
    """Named suppliers (fields of a report); a name has one supplier at a time."""

    def __init__(self) -> None:
        self._items: dict[str, V] = {}

    def add(self, name: str, item: V) -> Remove:
        if name in self._items:
            raise ValueError(f"{name!r} is already supplied")
        self._items[name] = item

        def remove() -> None:
            if self._items.get(name) is item:
                del self._items[name]

        return remove

    def items(self) -> list[tuple[str, V]]:
        return list(self._items.items())

    def __contains__(self, name: object) -> bool:
        return name in self._items

    def __getitem__(self, name: str) -> V:
        return self._items[name]
