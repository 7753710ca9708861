"""pyinfra configuration, read before the inventory (from the directory
pyinfra runs in: inventories/ refuse any other, see robotfleet.inventory)."""

import os
import sys

# The checkout's roles/ first, before anything installed under that name
# (pyinfra appends the deploy directory to sys.path, after site-packages).
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from pyinfra import config

from robotfleet.inventory import refuse, require_python_inventory

config.REQUIRE_PYINFRA_VERSION = ">=3.10,<4"

# pyinfra treats a mistyped inventory path as an empty inventory and exits 0
# having done nothing; refuse it instead.
_missing = [a for a in sys.argv[1:] if a.endswith(".py") and not a.startswith("-") and not os.path.exists(a)]
if _missing:
    refuse([f"{path}: no such file" for path in _missing])

# pyinfra takes a Python inventory: a fleet file or an Ansible inventory
# directory given to it gets one line naming the form that works.
require_python_inventory()
