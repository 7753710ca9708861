"""This machine, provisioned as one of the fleet's laptops without SSH:

    pyinfra inventories/local.py deploy.py

Its settings are its entry under `laptops` in robots.yaml (or the file named
by $ROBOT_FLEET), found by host name (or $ROBOT_FLEET_HOST).

sudo and its password (robotfleet/localsudo.py): before anything runs, sudo
is asked whether it needs a password.  In a terminal it then asks for it
once, itself, and the steps use its cached credentials; with no terminal the
run stops with one line saying how on (--use-sudo-password, or a sudoers
line).  With --use-sudo-password (or if sudo's cached credentials expire in
a long run) pyinfra asks and passes the password to every sudo command in
that command's own argument list (pyinfra/connectors/util.py), where every
local user can read it for a moment (ps, /proc/<pid>/cmdline; measured by
tests/bench/sudo_password.py).  On a laptop other people log in to, give the
deploying user passwordless sudo for the run and take it back after, or
mount /proc with hidepid=2 (see docs/explanations/security.md); on a single-user laptop
the exposure is to yourself.
"""

import os
import socket
from pathlib import Path

from robotfleet.inventory import display_path, load_or_exit, refuse, require_checkout
from robotfleet.localsudo import require as require_sudo

require_checkout()

_path = Path(os.environ.get("ROBOT_FLEET") or Path(__file__).with_name("robots.yaml"))
_fleet = load_or_exit(_path)
_name = os.environ.get("ROBOT_FLEET_HOST") or socket.gethostname()
_mine = [data for name, data in _fleet.hosts("laptops") if name == _name]
if not _mine:
    _known = ", ".join(name for name, _ in _fleet.hosts("laptops")) or "none"
    refuse(
        [
            f"{display_path(_path)}: no laptop named {_name!r} (laptops: {_known}); "
            "add this machine or set ROBOT_FLEET_HOST"
        ]
    )

require_sudo("@local")
laptops = [("@local", {k: v for k, v in _mine[0].items() if not k.startswith("ssh_")})]
