"""Named plug-ins at SEAL's seams (policies, verifiers, scorers, methods), in the spirit of LeRobot's
``make_policy`` / ``make_env``: a new model is one registered factory, with its options, and
nothing else.

An entry is a factory or the dotted path ``"package.module:attr"`` of one, plus the plug-in's
options (a frozen dataclass of `seal.options.Options`: its settings, their CLI flags, its canonical
form and its checkpoint digest). Paths are imported on first use, so naming a plug-in costs nothing
and a registry never drags a heavy (or upward) dependency into the module that owns it; options
classes are light by rule (they never load a model), so they are given as classes.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from importlib import import_module
from typing import Any, Callable

from seal.errors import InvalidInput
from seal.options import Options


@dataclass(frozen=True)
class Plugin:
    factory: str | Callable[..., Any]
    options: type[Options] = Options
    summary: str = ""  # one line for the selector's help (``--policy NAME``: what NAME is)


class Registry:
    def __init__(self, kind: str, entries: dict[str, str | Callable[..., Any] | Plugin]):
        self.kind = kind
        self._entries = {name: e if isinstance(e, Plugin) else Plugin(e) for name, e in entries.items()}

    def register(self, name: str, factory: str | Callable[..., Any], options: type[Options] = Options,
                 summary: str = "") -> None:
        """Add (or replace) a plug-in: ``options`` are its settings (`seal.options.Options`)."""
        self._entries[name] = Plugin(factory, options, summary)

    def unregister(self, name: str) -> None:
        self._entries.pop(name, None)

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self):
        return iter(self._entries)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._entries)

    def _entry(self, name: str) -> Plugin:
        if name not in self._entries:
            raise InvalidInput(f"unknown {self.kind} {name!r}; valid: {', '.join(self._entries)}")
        return self._entries[name]

    def plugin(self, name: str) -> Plugin:
        return self._entry(name)

    def options(self, name: str) -> type[Options]:
        """The options class of a plug-in."""
        return self._entry(name).options

    def option_names(self) -> set[str]:
        """Every option some plug-in of this registry declares."""
        return {f.name for name in self._entries for f in fields(self._entries[name].options)}

    def options_of(self, name: str, source) -> Options:
        """``name``'s options: ``source`` itself when it is one, else read field by field from
        ``source`` (a `MethodSpec`, or any object with those attributes)."""
        cls = self.options(name)
        if isinstance(source, cls):
            return source
        return cls(**{f.name: getattr(source, f.name) for f in fields(cls) if hasattr(source, f.name)})

    def factory(self, name: str) -> Callable[..., Any]:
        entry = self._entry(name).factory
        if isinstance(entry, str):
            module, _, attr = entry.partition(":")
            entry = import_module(module)
            for part in attr.split("."):
                entry = getattr(entry, part)
        return entry

    def make(self, name: str, *args, **kwargs):
        return self.factory(name)(*args, **kwargs)
