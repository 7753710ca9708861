"""Bring a robot or an operator laptop to its declared state.

    pyinfra inventories/robots.py deploy.py

ROLES is the one list of roles, in the order they run on each host: each
names its folder under roles/, one a line, so adding a role is its folder
and one line here (the gpu role first: a host without a loaded driver fails
before anything is installed).  Each host's state is read with one command;
the roles then change only what differs.  Robots get everything; laptops get
Docker (and its users), X11 and the payload staged (no autostart unless
payload_autostart is set).
"""

from robotfleet.provision import provision
from roles import named

ROLES = named(
    "gpu",
    "docker",
    "time",
    "udev",
    "x11",
    "payload",
    "pull",
)

provision(ROLES)
