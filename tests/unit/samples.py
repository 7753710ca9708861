"""Sample values and hosts that a unit test module and its integration twin
(or another module) share: written once here, never imported from a
test_*.py."""

from __future__ import annotations

from robotfleet.host.fixtures import file_state
from tests.unit.harness import ROBOT, converged

UNIT = "/etc/systemd/system/robot-payload.service"  # the payload's unit, as the payload role writes it
DAEMON_JSON = "/etc/docker/daemon.json"
DRIFTED = '{\n  "live-restore": false\n}\n'  # a daemon.json someone edited on the robot
AMD64_LOCAL = {"id": "sha256:" + "1" * 64, "platform": {"os": "linux", "architecture": "amd64"}}


def drifted_robot():
    """A converged Debian 13 robot whose daemon.json was edited (DRIFTED)."""
    snap = converged("robots", ROBOT, "debian-13")
    snap.files[DAEMON_JSON] = file_state(DRIFTED)
    return snap


def result(deployment, ok, message):
    """payloadctl's structured result as the payload's status cells carry it."""
    return {
        "payloadctl": 1,
        "ok": ok,
        "outcome": "applied" if ok else "rolled-back",
        "message": message,
        "deployment": deployment,
    }


def lab_state(prefix="t"):
    """A lab's state.json (tests/lab/state.py), its exact keys."""
    return {
        "prefix": prefix,
        "ssh_key": "/k",
        "known_hosts": "/kh",
        "ssh_user": "ops",
        "hosts": [{"name": "robot1", "group": "robots", "container": f"{prefix}-robot1", "port": 22001}],
        "services_host": f"{prefix}-services",
        "apt_proxy": f"http://{prefix}-services:3142",
        "registry": f"{prefix}-services:5000",
        "registry_local": "127.0.0.1:25000",
        "mirror_url": f"http://{prefix}-services:8080/linux",
        "mirror_dir": "/m",
    }
