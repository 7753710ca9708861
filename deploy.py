"""Bring a robot or an operator laptop to its declared state.

    pyinfra inventories/robots.py deploy.py

Robots get everything; laptops get Docker, users, X11 and the payload image
(no autostart unless payload_autostart is set).  One command reads the host's
state; the roles then change only what differs.
"""

from pyinfra import host

from roles import docker, gpu, operations, payload, udev, users, x11
from roles.gpu import plan as gpu_plan
from roles.hoststate import HostSnapshot, SnapshotQuery
from roles.settings import data_problems

_ROLES = (gpu, docker, users, udev, x11, payload)


def _provision():
    query = SnapshotQuery()
    for role in _ROLES:
        role.declare_reads(host.data, query)
    snapshot = host.get_fact(HostSnapshot, **query.as_kwargs())

    if gpu_plan.wanted(host.data):
        gpu.nvidia_toolkit(snapshot)  # first: its preconditions fail the host before anything is installed
    docker.install_docker(snapshot)
    users.docker_users(snapshot)
    if host.data.sensors or host.data.udev_vendor_rules:
        udev.sensor_rules(snapshot)
    if host.data.display:
        x11.x11_cookie(snapshot)
    payload.deploy_payload(snapshot)


# The fleet file was checked before connecting; --data overrides were not.
_problems = data_problems(host.data)
if _problems:
    operations.fail(name="Check the host's settings", message="settings: " + "; ".join(_problems))
else:
    _provision()
