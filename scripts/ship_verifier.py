#!/usr/bin/env python
"""Ship a `seal train verifier` run as the package's learned verifier (maintainers' tool).

    python scripts/ship_verifier.py ../runs/verifier/r7_plain_soup --keep-as held_labels \\
        --keep-label "the round-2 VLA's rounds" --operating-point 0.9 \\
        --held-out subplan_protocol=../runs/verifier/r7_plain_soup/r4held_t0.9.json \\
        --held-out task_level=../runs/verifier/r7_plain_soup/task_t0.9.json --labels "..." --why "..."

The checkpoint it replaces stays loadable as learned:<keep-as>; see seal.verify.ship.
"""

import argparse
import sys

from seal.errors import InvalidInput
from seal.verify.ship import ship


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", help="a `seal train verifier` run directory")
    p.add_argument("--keep-as", required=True, help="name to keep the replaced checkpoint under (learned:NAME)")
    p.add_argument("--keep-label", default=None, help='reports call it "learned verifier from <this>"')
    p.add_argument("--operating-point", type=float, required=True, help="the threshold it is meant to run at")
    p.add_argument("--held-out", action="append", default=[], metavar="NAME=BENCH.json",
                   help="a `seal bench verifier` result of this run (repeat); one must be at the operating point")
    p.add_argument("--labels", default="", help="how its training and held-out cases were labelled")
    p.add_argument("--why", required=True, help="why this one ships (for the manifest)")
    args = p.parse_args()
    try:
        held_out = {}
        for item in args.held_out:
            name, sep, path = item.partition("=")
            if not sep or not name or not path:
                raise InvalidInput(f"--held-out takes NAME=BENCH.json, got {item!r}")
            held_out[name] = path
        path = ship(args.run, keep_as=args.keep_as, keep_label=args.keep_label, operating_point=args.operating_point,
                    held_out=held_out, labels=args.labels, why=args.why)
    except InvalidInput as exc:
        print(f"ship_verifier: error: {exc}", file=sys.stderr)
        return 2
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
