"""pyinfra configuration, read before the inventory."""

import os
import sys

from pyinfra import config

config.REQUIRE_PYINFRA_VERSION = ">=3.10,<4"

# pyinfra treats a mistyped inventory path as an empty inventory and exits 0
# having done nothing; refuse it instead.
for _argument in sys.argv[1:]:
    if _argument.endswith(".py") and not _argument.startswith("-") and not os.path.exists(_argument):
        print(f"{_argument}: no such file", file=sys.stderr)
        sys.stderr.flush()
        os._exit(2)
