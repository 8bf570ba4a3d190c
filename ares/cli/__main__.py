"""`python -m ares.cli ...`: the `ares` command, as the console script runs it."""

import sys

from ares.cli import main

sys.exit(main())
