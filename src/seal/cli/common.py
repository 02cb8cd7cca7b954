"""What the command modules share: the CLI's number types, the method options generated from
the registries (`seal run`, `seal eval`, `seal verify collect`), the policy and knobs help, and
the render warning. Command modules import this module and no other command module."""

from __future__ import annotations

import argparse
import sys

from seal.options import int_at_least, real_in

# one definition of these argparse types, shared with the plug-ins' options (`seal.options`)
COUNT = int_at_least(1)  # how many (steps, trials, workers, ...)
INDEX = int_at_least(0)  # which one, from 0
RATE = real_in(0.0, 1.0)  # a probability or rate
FRACTION = real_in(0.0, 1.0, high_open=True)  # a share held out (1 would leave nothing)
POSITIVE = real_in(0.0, low_open=True)  # seconds, minutes, a learning rate
NONNEGATIVE = real_in(0.0)


def warn_render(specs) -> None:
    """Say so (once per method) when a learned policy will see pixels unlike its training data."""
    for spec in specs:
        if (text := spec.render_warning()) is not None:
            print(f"seal: warning: {spec.label}: {text}", file=sys.stderr)


def method_flags(without=()) -> list:
    """The method options shared by `seal run`, `seal eval` and `seal verify collect`, generated from
    the loop's settings and every registered plug-in's options (`seal.steer.method.settings`): a
    flag per setting, its type and help (with the default) from the declaration. Defaults are None
    here (= not given), so MethodSpec's own apply and every command means the same by them."""
    from seal.steer.method import settings

    return [s for s in settings() if s.flag and s.name not in without]


def add_method_options(p: argparse.ArgumentParser, without=()) -> None:
    group = p.add_argument_group("method options (seal.steer.method.MethodSpec)")
    for setting in method_flags(without):
        group.add_argument(setting.option, type=setting.type, default=None, help=setting.help)


def method_settings(args) -> dict:
    """The method options given on the command line, as MethodSpec settings."""
    return {s.name: getattr(args, s.name) for s in method_flags() if getattr(args, s.name, None) is not None}


def policy_help(only=None) -> str:
    """The registered policies, each with its one-line summary (``only``: a filter on the names)."""
    from seal.policies import POLICIES

    names = [n for n in POLICIES.names if only is None or only(n)]
    return " | ".join(f"{n}{'[:PATH]' if POLICIES.options(n).checkpoint else ''}: {POLICIES.plugin(n).summary}"
                      for n in names)


def scripted_knobs() -> tuple[str, list[str]]:
    """The scripted expert's knobs setting: its default and choices, as its options declare them."""
    from seal.policies.options import KNOBS, ScriptedOptions

    return ScriptedOptions().knobs, list(KNOBS)
