"""A plug-in's settings: one frozen dataclass per policy, verifier or scorer, registered beside it.

Each field is declared with `option(default, help, ...)`. From these declarations alone:

- the CLI generates a flag per option (``--planner-model`` for ``planner_model``: its type, its help
  with the default appended), shared by `seal run`, `seal eval` and `seal verify collect`;
- ``--methods`` items parse ``name=value`` by the default's type (or the declared ``parse``);
- `Options.hashed` gives what enters a method's config hash: the hashed fields, minus those added
  after results stores existed while they are at their default (``later``, so older configurations
  keep their hashes) and minus a value every earlier result ran with (``legacy``);
- a plug-in with weights names the option that holds their path (``checkpoint``) and says where
  they are (`Options.weights`); the method description replaces that path by the weights' digest
  (`seal.checkpoint.CheckpointFormat.digest`), so retraining in place is a new method.

Options never load a model: the method description parses and hashes with them in any process.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, ClassVar

from seal.errors import InvalidInput

if TYPE_CHECKING:
    from seal.checkpoint import CheckpointFormat

_UNSET = object()  # no legacy value


def option(default: Any, help: str, *, choices: tuple | None = None, type: Callable[[str], Any] | None = None,
           parse: Callable[[str], Any] | None = None, what: str | None = None, later: bool = False,
           legacy: Any = _UNSET, hash: bool = True, strict: bool = False, flag: bool = True,
           per_method: bool = False) -> Any:
    """One setting of a plug-in (or of the loop).

    ``help`` says what it does; the CLI appends the default. ``choices``: the valid values (checked
    on construction, listed in the help). ``type``: the CLI's argparse type (default: the default's
    type); ``parse``: text -> value in a ``--methods`` item when the default's type cannot say.
    ``what``: how an error names it. ``later``: added after results stores existed, so it enters the
    config hash only when not at its default. ``legacy``: a value every earlier result ran with,
    left out of the hash. ``hash=False``: where a model runs, not what it is (hosts, URLs,
    timeouts). ``strict``: given with another plug-in selected, it is an error, not ignored.
    ``flag=False``: no CLI flag (set in ``--methods`` items only). ``per_method``: a loop setting
    that enters the hash only for the methods that use it (`seal.steer.selection.Selection.uses`)."""
    return field(default=default, metadata={"help": help, "choices": choices, "type": type, "parse": parse,
                                            "what": what, "later": later, "legacy": legacy, "hash": hash,
                                            "strict": strict, "flag": flag, "per_method": per_method})


def meta(f) -> dict:
    """An option's declaration (a field declared without `option` gets the plain defaults)."""
    return {"help": "", "choices": None, "type": None, "parse": None, "what": None, "later": False,
            "legacy": _UNSET, "hash": True, "strict": False, "flag": True, "per_method": False, **dict(f.metadata)}


def has_legacy(f) -> bool:
    return meta(f)["legacy"] is not _UNSET


def one_of(what: str, value, valid) -> None:
    if value not in valid:
        raise InvalidInput(f"unknown {what} {value!r}; valid: {', '.join(repr(v) if not v else v for v in valid)}")


def check_choices(obj) -> None:
    """Every option with ``choices`` holds one of them."""
    for f in fields(obj):
        m = meta(f)
        if m["choices"] is not None:
            one_of(m["what"] or f.name, getattr(obj, f.name), m["choices"])


def default_of(f):
    return f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc]


def hashed(obj, names=None) -> dict:
    """The fields of ``obj`` that enter a config hash, in declaration order (``names``: only these)."""
    out = {}
    for f in fields(obj):
        m, value = meta(f), getattr(obj, f.name)
        if not m["hash"] or (names is not None and f.name not in names):
            continue
        if m["later"] and value == default_of(f):
            continue
        if m["legacy"] is not _UNSET and value == m["legacy"]:
            continue
        out[f.name] = list(value) if isinstance(value, tuple) else value
    return out


@dataclass(frozen=True)
class Options:
    """A plug-in's settings (subclass it, declare each field with `option`).

    ``checkpoint``: the option naming the plug-in's weights, or None; ``NAME:PATH`` fills it, and
    the method description hashes the weights' digest in its place."""

    checkpoint: ClassVar[str | None] = None

    def __post_init__(self) -> None:
        check_choices(self)

    def hashed(self) -> dict:
        """The settings that change results, before the checkpoint's path is replaced by its digest."""
        return hashed(self)

    def weights(self) -> tuple["CheckpointFormat", Path]:
        """(format, directory) of the weights ``checkpoint`` names (plug-ins with a checkpoint)."""
        raise NotImplementedError(f"{type(self).__name__} names no checkpoint")

    def digest(self) -> str:
        """What names the weights in a results store: their verified bytes, never their path."""
        fmt, directory = self.weights()
        return fmt.digest(directory)

    def check_in_use(self, method: str) -> None:
        """Refuse settings this plug-in cannot run with, once a method is known to use it."""

    def preferred_render(self) -> str | None:
        """The render model this plug-in's inputs come from (None: no preference)."""
        return None

    def render_warning(self, render: str) -> str | None:
        """Why ``render``'s pixels differ from the ones this plug-in learned from (None: they do not)."""
        return None


# ---- text -> value for CLI flags (argparse types: a bad value ends as `seal: error: argument --x: ...`)
def int_at_least(low: int, high: int | None = None) -> Callable[[str], int]:
    """An integer in ``low``..``high`` (a count, an index, a port)."""

    def parse(text: str) -> int:
        value = int(text)  # not a number: argparse's own "invalid int value: 'x'"
        if value < low or (high is not None and value > high):
            valid = f">= {low}" if high is None else f"in {low}..{high}"
            raise argparse.ArgumentTypeError(f"must be an integer {valid}, got {value}")
        return value

    parse.__name__ = "int"
    return parse


def real_in(low: float, high: float | None = None, *, low_open: bool = False,
            high_open: bool = False) -> Callable[[str], float]:
    """A finite number in the interval from ``low`` to ``high`` (open ends as said; no ``high``: unbounded)."""
    if high is None:
        valid = f"{'>' if low_open else '>='} {low:g}"
    else:
        valid = f"in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"

    def parse(text: str) -> float:
        value = float(text)  # not a number: argparse's own "invalid float value: 'x'"
        inside = (value > low if low_open else value >= low) and (
            high is None or (value < high if high_open else value <= high))
        if not math.isfinite(value) or not inside:
            raise argparse.ArgumentTypeError(f"must be a number {valid}, got {text}")
        return value

    parse.__name__ = "float"
    return parse


def cli_type(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type from a ``parse`` that raises `InvalidInput` (its message becomes argparse's)."""

    def convert(text: str):
        try:
            return parse(text)
        except InvalidInput as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    convert.__name__ = getattr(parse, "__name__", "value")
    return convert


COUNT = int_at_least(1)  # how many (candidates, rounds, steps)
RATE = real_in(0.0, 1.0)  # a probability or rate
POSITIVE = real_in(0.0, low_open=True)  # seconds
PORT = int_at_least(1, 65535)
