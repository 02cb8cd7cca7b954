"""Named plug-ins at SEAL's seams (policies, verifiers, scorers), in the spirit of LeRobot's
``make_policy`` / ``make_env``: a new model is one registered factory and nothing else.

An entry is a factory or the dotted path ``"package.module:attr"`` of one; paths are imported on
first use, so naming a plug-in costs nothing and a registry never drags a heavy (or upward)
dependency into the module that owns it.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any, Callable

from seal.errors import InvalidInput


class Registry:
    def __init__(self, kind: str, entries: dict[str, str | Callable[..., Any]]):
        self.kind = kind
        self._entries = dict(entries)

    def register(self, name: str, factory: str | Callable[..., Any]) -> None:
        """Add (or replace) a plug-in; the learned models register themselves this way."""
        self._entries[name] = factory

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self):
        return iter(self._entries)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._entries)

    def factory(self, name: str) -> Callable[..., Any]:
        if name not in self._entries:
            raise InvalidInput(f"unknown {self.kind} {name!r}; valid: {', '.join(self._entries)}")
        entry = self._entries[name]
        if isinstance(entry, str):
            module, _, attr = entry.partition(":")
            entry = import_module(module)
            for part in attr.split("."):
                entry = getattr(entry, part)
        return entry

    def make(self, name: str, *args, **kwargs):
        return self.factory(name)(*args, **kwargs)
