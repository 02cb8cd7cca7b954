#!/usr/bin/env python
"""Ship a `seal train value` run as a named Q-function of the package (maintainers' tool).

    python scripts/ship_value.py ../runs/value/l10_64_v --as l10_demos \
        --note "seal train value --dataset ../runs/data/l10_64_v (150 demonstrations)"

`value_ckpt=<name>` then loads it on any clone; see seal.value.ship.
"""

import argparse
import sys

from seal.errors import InvalidInput
from seal.value.ship import ship


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", help="a `seal train value` run directory")
    p.add_argument("--as", dest="name", required=True, help="the shipped name (a new one: names are never reused)")
    p.add_argument("--note", default="", help="a line for the manifest (the command, why this one ships)")
    args = p.parse_args()
    try:
        print(ship(args.run, args.name, note=args.note))
    except InvalidInput as exc:
        print(f"ship_value: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
