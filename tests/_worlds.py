"""A real LIBERO world at a given init state, closed afterwards (for module-scoped fixtures)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from seal.sim.world import LiberoWorld


@contextmanager
def world_at(suite: str, task: int, init: int = 0) -> Iterator[LiberoWorld]:
    w = LiberoWorld((suite, task))
    try:
        w.reset(init)
        yield w
    finally:
        w.close()
