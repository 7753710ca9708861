"""Pure decisions of the pull role: the agent's configuration, its systemd
units and the python a robot has, computed from the host's data."""

from __future__ import annotations

import shlex

from robotfleet.pull import layout

HEADER = "# Managed by the robot fleet provisioner (roles/pull); local edits are overwritten.\n"
PACKAGES = ("python3-venv", "git", "openssh-client")
# The python a release of Debian or Ubuntu ships (python3), for a host that
# has none yet: its wheels are chosen before python3 is installed.
DISTRIBUTION_PYTHON = {
    ("debian", "11"): "39", ("debian", "12"): "311", ("debian", "13"): "313",
    ("ubuntu", "20.04"): "38", ("ubuntu", "22.04"): "310", ("ubuntu", "24.04"): "312",
}
# dpkg's architecture -> what Python calls the machine (platform.machine()).
MACHINES = {"amd64": "x86_64", "arm64": "aarch64", "armhf": "armv7l", "i386": "i686"}
PYTHON_PROBE = "python3 -c 'import sys; print(\"%d%d\" % sys.version_info[:2])'"


def config(data, robot: str) -> layout.Config:
    return layout.Config(
        robot=robot,
        remote=data.pull_remote,
        interval=data.pull_interval,
        jitter=data.pull_jitter,
        windows=tuple(data.pull_windows),
        min_free_mb=data.pull_min_free_mb,
        fetch_timeout=data.pull_fetch_timeout,
        stale_after=data.pull_stale_after,
    )


def known_hosts(data) -> str:
    """The git server's keys for the agent's ssh, whatever name it is reached by
    (the agent's ssh is told the host's key alias; see robotfleet/pull/transport.py)."""
    return "".join(f"{KNOWN_HOSTS_ALIAS} {key}\n" for key in data.pull_remote_host_keys)


# ssh looks the server up under this name (HostKeyAlias), so a key is
# pinned to the fleet remote whatever address or port reaches it.
KNOWN_HOSTS_ALIAS = "robotfleet-remote"


def platform(probed_python: str, os_release: dict, arch: str) -> str | None:
    """The robot's wheel platform, e.g. cp313-x86_64; None when unknown."""
    version = probed_python.strip()
    if not version.isdigit():
        version = DISTRIBUTION_PYTHON.get((os_release.get("id", ""), os_release.get("version_id", "")), "")
    machine = MACHINES.get(arch)
    return f"cp{version}-{machine}" if version and machine else None


def keygen_script(robot: str) -> str:
    """Make the robot's key pair beside its place, then rename it into place."""
    key = layout.KEY
    return f"""set -e
umask 077
tmp=$(mktemp -d {layout.ETC}/.key.XXXXXX); trap 'rm -rf "$tmp"' EXIT
ssh-keygen -q -t ed25519 -N '' -C 'robot-pull@'{shlex.quote(robot)} -f "$tmp/key"
mv -T "$tmp/key.pub" {key}.pub
mv -T "$tmp/key" {key}
"""


def service_unit() -> str:
    return HEADER + f"""[Unit]
Description=Robot fleet pull agent: fetch, verify and apply a signed release (docs/pull.md)
Wants=network-online.target
After=network-online.target
ConditionPathExists={layout.CONFIG}

[Service]
Type=oneshot
WorkingDirectory={layout.CURRENT_CODE}
Environment=PYTHONPATH={layout.CURRENT_CODE} PYTHONDONTWRITEBYTECODE=1
ExecStart={layout.VENV}/bin/python -m robotfleet.pull.agent --config {layout.CONFIG}
# A release may install Docker and pull images: hours, not the default 90 s.
TimeoutStartSec=4h
Nice=10
IOSchedulingClass=best-effort
IOSchedulingPriority=7
"""


def timer_unit(data) -> str:
    # Persistent= acts only on OnCalendar= timers; a robot that was off
    # catches up through OnBootSec=, the first check after each boot.
    return HEADER + f"""[Unit]
Description=Robot fleet pull agent: check for a new release every {data.pull_interval} s

[Timer]
OnBootSec={data.pull_boot_delay}
OnActiveSec={data.pull_boot_delay}
OnUnitInactiveSec={data.pull_interval}
RandomizedDelaySec={data.pull_jitter}
Persistent=true
AccuracySec=1s

[Install]
WantedBy=timers.target
"""
