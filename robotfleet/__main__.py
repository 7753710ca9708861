"""`python3 -m robotfleet ...`: the same as the `robotfleet` command."""

import sys

from robotfleet.cli import main

sys.exit(main())
