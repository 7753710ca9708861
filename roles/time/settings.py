"""The time role's settings: the fleet's time servers, and which hosts serve."""

from __future__ import annotations

import re

from robotfleet import checkers as c
from robotfleet import value_kinds as v
from robotfleet.role import Setting

# chrony's server and allow lines take no IPv6 zone (%eth0).
SERVER = rf"{v.IPV4}|{v.IPV6_NO_ZONE}|{v.DNS_NAME}"
NETWORK = rf"{v.IPV4}(?:/(?:3[0-2]|[12]?[0-9]))?|{v.IPV6_NO_ZONE}(?:/(?:12[0-8]|1[01][0-9]|[1-9]?[0-9]))?"
_SERVER = re.compile(SERVER, re.ASCII)
_NETWORK = re.compile(NETWORK, re.ASCII)


def server(value):
    """A host name or an IP address chrony can poll (one word of chrony.conf)."""
    problems = v.address(value)
    if not problems and not _SERVER.fullmatch(value):
        return [("", f"expected a host name or an IP address without a zone (%interface), got {c.shown(value)}")]
    return problems


def network(value):
    """A network (CIDR) or a single address that may ask a serving host for time."""
    if not isinstance(value, str):
        return [("", c.expected_string(value, "a network like 10.20.0.0/24 or an address"))]
    if not _NETWORK.fullmatch(value):
        return [("", f"expected a network like 10.20.0.0/24 or an address, got {c.shown(value)}")]
    return []


c.with_schema(
    server,
    {"type": "string", "pattern": c.json_pattern(SERVER), "description": "a host name or an IP address (no %zone)"},
)
c.with_schema(
    network,
    {"type": "string", "pattern": c.json_pattern(NETWORK), "description": "a network like 10.20.0.0/24, or an address"},
)

SETTINGS = (
    Setting(
        "time_servers",
        [],
        c.list_of(server, unique=True),
        "NTP servers this host follows with chrony (host names or addresses); the role runs where this "
        "is set or time_serve is true.",
    ),
    Setting(
        "time_serve",
        False,
        c.boolean,
        "This host serves time to time_allow, from its own clock at time_local_stratum when no server answers.",
    ),
    Setting(
        "time_allow",
        [],
        c.list_of(network, unique=True),
        "Networks (10.20.0.0/24) or addresses that may ask this host for time; required when time_serve is true.",
    ),
    Setting(
        "time_set_clock",
        True,
        c.boolean,
        "chrony sets the system clock; false: it only tracks and serves time (chronyd -x, for containers).",
    ),
    Setting(
        "time_local_stratum",
        10,
        c.integer(1, 15),
        "The stratum a serving host announces while it serves from its own clock.",
    ),
)


def rules(data: dict, refused: frozenset) -> list[c.Problem]:
    problems = []
    if data.get("time_serve") is True and not {"time_serve", "time_allow"} & refused and not data.get("time_allow"):
        problems.append(
            (
                "time_allow",
                "required when time_serve is true: the networks that may ask this host "
                "for time (e.g. 10.20.0.0/24); nothing is open by default",
            )
        )
    own = data.get("ssh_hostname")
    if "time_servers" not in refused and isinstance(own, str) and own in (data.get("time_servers") or []):
        index = data["time_servers"].index(own)
        problems.append(
            (
                f"time_servers[{index}]",
                f"{own} is this host itself; a host does not follow its own "
                "clock (give it time_servers: [] or other servers)",
            )
        )
    return problems
