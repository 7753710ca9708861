"""Pure decisions of the pull role: the agent's configuration, its systemd
units and the python a robot has, computed from the host's data."""

from __future__ import annotations

import shlex

from robotfleet.fleet import connection
from robotfleet.pull.protocol import agent_files, robot_key
from robotfleet.role import PullPart
from roles.pull.settings import SETTINGS

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


# The pull settings, and the connection settings the agent reuses (its keepalives).
_DEFAULTS = {setting.name: setting.default for setting in (*SETTINGS, *connection.SETTINGS)}


def value(data, name: str):
    """The pull or connection setting ``name`` of a host's data (pyinfra's,
    the fleet file's, or a mapping): its declared default where the data has none."""
    found = data.get(name) if hasattr(data, "get") else getattr(data, name, None)
    return _DEFAULTS[name] if found is None else found


def pulls(data) -> bool:
    return value(data, "pull_enabled") is True


def config(data, robot: str, **extra) -> agent_files.Config:
    """The agent's configuration for a host with ``data``."""
    return agent_files.Config(
        robot=robot,
        remote=value(data, "pull_remote"),
        interval=value(data, "pull_interval"),
        jitter=value(data, "pull_jitter"),
        windows=tuple(value(data, "pull_windows")),
        min_free_mb=value(data, "pull_min_free_mb"),
        fetch_timeout=value(data, "pull_fetch_timeout"),
        keepalive_interval=value(data, "ssh_keepalive_interval"),
        keepalive_count_max=value(data, "ssh_keepalive_count_max"),
        stale_after=value(data, "pull_stale_after"),
        heartbeat=value(data, "pull_heartbeat"),
        report_remote=value(data, "pull_report_remote"),
        report_shards=value(data, "pull_report_shards"),
        media_dir=value(data, "pull_media_dir"),
        extra=extra,
    )


def known_hosts(data) -> str:
    """The git server's keys (pull_remote_host_keys), as the agent's known_hosts."""
    return agent_files.known_hosts(value(data, "pull_remote_host_keys"))


KNOWN_HOSTS_ALIAS = agent_files.HOST_KEY_ALIAS


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


service_unit = agent_files.service_unit


def timer_unit(data) -> str:
    return agent_files.timer_unit(
        value(data, "pull_interval"), value(data, "pull_jitter"), value(data, "pull_boot_delay")
    )


PART = PullPart(
    pulls=pulls,
    config=config,
    platform=lambda data: value(data, "pull_platform"),
    known_hosts=known_hosts,
    timer=timer_unit,
    trust_root=lambda data: value(data, "pull_trust_root"),
    remote_ca=lambda data: value(data, "pull_remote_ca"),
)
