"""The engine: what runs the roles, and knows none of them by name.

- ``engine/role.py``: what a role declares (settings, host reads, steps, hooks);
- ``engine/host/``: the host snapshot (one SSH command) and the operations that
  compare against it, the apt helpers, the pinned apt repository;
- ``engine/fleet/``: the fleet file (reading, checking, the editors' schema);
- ``engine/roster.py`` and ``engine/play.py``: the roles deploy.py lists, run on a host;
- ``engine/commands/``: the operator commands (``python3 -m engine ...``).

The engine runs from its checkout (the deploy repository: deploy.py,
inventories/, files/ sit beside it, and pyinfra is started there).  A copy
installed without its checkout (a wheel, ``pip install .``) would have none of
those, and would shadow the checkout's (pyinfra appends the deploy directory
to sys.path after site-packages), so it refuses to load.
"""

from pathlib import Path

CHECKOUT = Path(__file__).resolve().parent.parent

if not (CHECKOUT / "deploy.py").is_file():
    raise ImportError(
        f"engine: {Path(__file__).resolve().parent} is not in a checkout of the robot fleet provisioner "
        "(no deploy.py beside it); it runs from its checkout: in the checkout, "
        "python3 -m venv .venv && .venv/bin/pip install -e .  (README: Install for operators)"
    )
