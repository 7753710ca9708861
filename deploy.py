"""Bring a robot or an operator laptop to its declared state.

    pyinfra inventories/robots.py deploy.py

Robots get everything; laptops get Docker, users, X11 and the payload image
(no autostart unless payload_autostart is set).  One command reads the host's
state; the roles then change only what differs.
"""

from pyinfra import host

from roles import docker, payload, udev, users, x11
from roles.hoststate import HostSnapshot, Query

_ROLES = (docker, users, udev, x11, payload)

_query = Query()
for _role in _ROLES:
    _role.wants(host.data, _query)
_snapshot = host.get_fact(HostSnapshot, **_query.as_kwargs())

docker.install_docker(_snapshot)
users.docker_users(_snapshot)
if host.data.sensors or host.data.udev_vendor_rules:
    udev.sensor_rules(_snapshot)
if host.data.display:
    x11.x11_cookie(_snapshot)
payload.deploy_payload(_snapshot)
