"""The `seal` command. Thin: parse arguments, call one function, print the result."""

# One module per command (seal.cli.run, .eval, .train, ...): each has `add(sub)`, which adds its
# sub-parser, flags and the function it calls (`_cmd_<command>`). Command modules share only
# seal.cli.common (number types, the method options generated from the registries, the render
# warning); they never import each other. This module builds the top-level parser from COMMANDS and
# holds `main`, the `seal` console entry point (`python -m seal.cli` runs it too).

from __future__ import annotations

import argparse
import re
import sys

from seal.cli import annotate, bench, demos, eval, ground, report, run, serve, suites, train, verify
from seal.errors import SealError

# in the order `seal --help` lists them
COMMANDS = (run, ground, demos, train, verify, suites, eval, report, serve, annotate, bench)


class _Parser(argparse.ArgumentParser):
    """Every bad value ends the same way: ``seal: error: ...`` on stderr and exit status 2."""

    def error(self, message: str):
        # A bad value of a known option is said in one line (what was given, what is valid); the
        # usage helps only when the command line itself is malformed (a missing or unknown option).
        if not re.match(r"argument [^:]+: (invalid|must be)", message):
            self.print_usage(sys.stderr)
        self.exit(2, f"seal: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="seal", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add(sub)
    return p


def _terminate(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM cleans up like Ctrl-C: workers stopped, files closed


def main(argv: list[str] | None = None) -> int:
    import signal

    args = build_parser().parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # the command as typed (run manifests)
    signal.signal(signal.SIGTERM, _terminate)
    try:
        return args.func(args)
    except SealError as exc:
        print(f"seal: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("seal: interrupted", file=sys.stderr)
        return 130
