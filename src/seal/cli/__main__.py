"""`python -m seal.cli ...`: the same as the `seal` command."""

import sys

from seal.cli import main

sys.exit(main())
