"""Pure decisions of the time role: chrony's configuration and its unit's
drop-in, computed from the host's data, so they test without a host."""

from __future__ import annotations

import ipaddress

CONF = "/etc/chrony/chrony.conf"
UNIT = "chrony.service"
DROP_IN = "/etc/systemd/system/chrony.service.d/robot-time.conf"
# Time daemons that conflict with chrony (Debian's and Ubuntu's packages all
# provide and conflict with time-daemon): installing chrony removes them.
OTHER_DAEMONS = ("systemd-timesyncd", "ntp", "ntpsec", "openntpd")
CAP_SYS_TIME = 25  # linux/capability.h

HEADER = (
    "# Managed by the robot fleet provisioner (roles/time) from the fleet file's\n"
    "# time_* settings; local edits are overwritten.\n"
)

# chronyd -p (print the configuration after parsing it) came with chrony 4.0;
# 3.x would take -p for a configuration line and fork a daemon first, so it
# is asked only of chronyd 4 and later (Ubuntu 20.04 ships 3.5: not checked).
VALIDATE = (
    "major=$(chronyd -v 2>/dev/null | sed -n 's/^chronyd (chrony) version \\([0-9][0-9]*\\)\\..*/\\1/p'); "
    'if [ "${major:-0}" -ge 4 ]; then chronyd -p -f {} >/dev/null; fi'
)


def networks(allow: list[str]) -> list[str]:
    """time_allow as chrony reads it: each entry as its network (10.20.0.7/24 -> 10.20.0.0/24)."""
    return [str(ipaddress.ip_network(entry, strict=False)) for entry in allow]


def chrony_conf(data) -> str:
    """The whole of /etc/chrony/chrony.conf: only what the fleet file says
    (no pool, no DHCP or sources.d servers), valid for chrony 3.5 to 4.x."""
    lines = [HEADER]
    if data.time_servers:
        lines += [f"server {name} iburst" for name in data.time_servers]
    else:
        lines.append("# No time_servers: this host keeps its own clock.")
    lines += [
        "",
        "driftfile /var/lib/chrony/chrony.drift",
        "# Step the clock when it is off by more than a second in the first three",
        "# updates (a robot without a real-time clock boots far off); slew after.",
        "makestep 1 3",
        "rtcsync",
    ]
    if data.time_serve:
        lines += [
            "",
            "# time_serve: these may ask this host for time; it answers from its own",
            "# clock at this stratum while none of its servers does.",
            *(f"allow {net}" for net in networks(data.time_allow)),
            f"local stratum {data.time_local_stratum}",
        ]
    return "\n".join(lines) + "\n"


def drop_in() -> str:
    """The chrony.service drop-in for time_set_clock: false."""
    return (
        "# Managed by the robot fleet provisioner (roles/time): time_set_clock is false,\n"
        "# so chronyd tracks and serves time but never sets the system clock (-x).\n"
        "[Unit]\n"
        "# The packaged unit skips itself without CAP_SYS_TIME (a container); -x needs none.\n"
        "ConditionCapability=\n"
        "\n"
        "[Service]\n"
        "# In the foreground (-n), whatever type the packaged unit has.\n"
        "Type=simple\n"
        "PIDFile=\n"
        "ExecStart=\n"
        "ExecStart=!/usr/sbin/chronyd -n -x $DAEMON_OPTS\n"
    )


def can_set_clock(bounding_set: str) -> bool | None:
    """Whether the service manager may hand CAP_SYS_TIME to a service (the
    capability bounding set of PID 1, hex, as /proc/1/status shows it); None
    when the snapshot could not read it."""
    try:
        return bool(int(bounding_set.strip(), 16) >> CAP_SYS_TIME & 1)
    except ValueError:
        return None


def replaced(installed) -> list[str]:
    """The other time daemons installing chrony removes from this host."""
    return [name for name in OTHER_DAEMONS if name in installed]
