"""robotfleet: the engine of the robot fleet provisioner, and its command.

What runs the roles, and knows none of them by name:

- ``robotfleet/role.py``: what a role declares (settings, host reads, steps, hooks);
- ``robotfleet/host/``: the host snapshot (one SSH command) and the operations that
  compare against it, the apt helpers, the pinned apt repository;
- ``robotfleet/fleet/``: the fleet file (reading, checking, the editors' schema);
- ``robotfleet/deploy_roles.py`` and ``robotfleet/provision.py``: the roles deploy.py lists, run on a host;
- ``robotfleet/commands/``: the operator commands (``robotfleet ...``).

It runs from its checkout, the deploy repository: deploy.py, roles/,
inventories/ and files/ sit beside this package, and the roles are imported
from there (put first on sys.path, so that no other installed package named
``roles`` can stand in for them).  Only this package is installed (``pip
install -e .``); a copy installed without its checkout (a wheel, ``pip
install .``) has no roles and no deploy.py, and refuses with one line.
"""

import sys
from pathlib import Path

__version__ = "0.4.0"

CHECKOUT = Path(__file__).resolve().parent.parent
NOT_A_CHECKOUT = (
    f"robotfleet: {Path(__file__).resolve().parent} is not in a checkout of the robot fleet provisioner "
    "(no deploy.py beside it); it runs from its checkout: in the checkout, "
    "python3 -m venv .venv && .venv/bin/pip install -e .  (README: Install for operators)"
)

if not (CHECKOUT / "deploy.py").is_file():
    print(NOT_A_CHECKOUT, file=sys.stderr)
    raise SystemExit(2)

if str(CHECKOUT) not in sys.path[:1]:
    sys.path.insert(0, str(CHECKOUT))
