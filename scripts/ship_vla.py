#!/usr/bin/env python
"""Ship a `seal train vla` run as a named checkpoint of the package (maintainers' tool).

    python scripts/ship_vla.py ../runs/vla/r3 --as reason --keep-as reason_r0 \
        --keep-label "reasoning VLA (round 0)" --note "DAgger round 3"

The checkpoint being replaced stays loadable as vla:<keep-as>; see seal.policies.vla.ship.
"""

import argparse
import sys

from seal.errors import InvalidInput
from seal.policies.vla.ship import ship


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", help="a `seal train vla` run directory (or a checkpoint directory)")
    p.add_argument("--as", dest="name", required=True, help="the shipped name: reason or twin")
    p.add_argument("--keep-as", default=None, help="name to keep the checkpoint it replaces under")
    p.add_argument("--label", default=None, help="what reports call the new checkpoint (default: by its name)")
    p.add_argument("--keep-label", default=None, help="what reports call the kept checkpoint from now on")
    p.add_argument("--note", default="", help="a line for the manifest (why this one ships)")
    args = p.parse_args()
    try:
        path = ship(args.run, args.name, keep_as=args.keep_as, label=args.label, keep_label=args.keep_label,
                    note=args.note)
    except InvalidInput as exc:
        print(f"ship_vla: error: {exc}", file=sys.stderr)
        return 2
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
