"""The provisioner's roles.

They run from the project's checkout, which is the deploy repository:
deploy.py, inventories/, group_data/ and files/ sit beside roles/, and pyinfra
is started there.  A copy of roles installed without its checkout (a wheel,
``pip install .``) would have none of those, and would shadow the checkout's
roles (pyinfra appends the deploy directory to sys.path after site-packages),
so it refuses to load.  Install editable: ``pip install -e .`` in the checkout.
"""

from pathlib import Path

CHECKOUT = Path(__file__).resolve().parent.parent

if not (CHECKOUT / "deploy.py").is_file():
    raise ImportError(
        f"roles: {Path(__file__).resolve().parent} is not in a checkout of the robot fleet provisioner "
        "(no deploy.py beside it); it runs from its checkout: in the checkout, "
        "python3 -m venv .venv && .venv/bin/pip install -e .  (README: Install for operators)"
    )
