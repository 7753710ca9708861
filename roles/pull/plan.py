"""Pure decisions of the pull role: what it installs and the python a
robot has.  The agent's configuration and units are the host's pull
settings (robotfleet/pull/protocol/agent_files.py ``for_host``, ``timer_unit``)."""

from __future__ import annotations

import shlex

from robotfleet.pull.protocol import robot_key

PACKAGES = ("python3-venv", "git", "openssh-client")
# The python a release of Debian or Ubuntu ships (python3), for a host that
# has none yet: its wheels are chosen before python3 is installed.
DISTRIBUTION_PYTHON = {
    ("debian", "11"): "39",
    ("debian", "12"): "311",
    ("debian", "13"): "313",
    ("ubuntu", "20.04"): "38",
    ("ubuntu", "22.04"): "310",
    ("ubuntu", "24.04"): "312",
}
# dpkg's architecture -> what Python calls the machine (platform.machine()).
MACHINES = {"amd64": "x86_64", "arm64": "aarch64", "armhf": "armv7l", "i386": "i686"}
PYTHON_PROBE = "python3 -c 'import sys; print(\"%d%d\" % sys.version_info[:2])'"


def platform(probed_python: str, os_release: dict, arch: str) -> str | None:
    """The robot's wheel platform, e.g. cp313-x86_64; None when unknown."""
    version = probed_python.strip()
    if not version.isdigit():
        version = DISTRIBUTION_PYTHON.get((os_release.get("id", ""), os_release.get("version_id", "")), "")
    machine = MACHINES.get(arch)
    return f"cp{version}-{machine}" if version and machine else None


def keygen_script(robot: str) -> str:
    """Make the robot's key pair on the robot (robotfleet/pull/protocol/robot_key.py), its comment naming it."""
    return robot_key.keygen_script("'robot-pull@'" + shlex.quote(robot))
