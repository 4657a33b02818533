# Registration points other parts plug into; every registration returns its own remover.
from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

F = TypeVar("F")
V = TypeVar("V")

Remove = Callable[[], None]


class HookList(Generic[F]):
    """An ordered list of callbacks; :meth:`add` returns the function that takes it out."""

    def __init__(self) -> None:
        self._items: list[F] = []
        self._snapshot: tuple[F, ...] = ()  # what iteration walks: safe to change meanwhile

    def add(self, item: F) -> Remove:
        self._items.append(item)
        self._snapshot = tuple(self._items)

        def remove() -> None:
            if item in self._items:
                self._items.remove(item)
                self._snapshot = tuple(self._items)

        return remove

    def __iter__(self) -> Iterator[F]:
        return iter(self._snapshot)

    def __len__(self) -> int:
        return len(self._items)


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
