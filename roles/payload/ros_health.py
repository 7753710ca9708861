"""``ros_health``: what a healthy release's ROS 1 graph shows, checked by
the release gate from the graph itself (payloadctl/rosgraph.py runs
payloadctl/rosgraph_probe.py inside the project's roscore container).

    ros_health:
      nodes: [/talker, /listener]     # registered with the master, answering
      topics: {/chatter: 2 Hz}        # published at least this often
      services: [/add_two_ints]       # offered, and taking a connection

Checked before connecting (ROS graph names, rates above 0 Hz, the keys
known), and refused without ``ros_roscore``: the probe runs in the
project's own roscore, the one place inside the graph's network whatever
the network mode.  The release's compose document carries it under
``x-ros-health`` (normalized: global names, rates in Hz)."""

from __future__ import annotations

import re

from robotfleet import checkers as c
from roles.payload.payloadctl.rosgraph import KEY
from roles.payload.services import value_of

SETTING = "ros_health"
KEYS = ("nodes", "topics", "services")
# A ROS graph resource name (ROS wiki, Names): segments starting with a letter, then letters, digits, _;
# relative names are taken from the root namespace (/), as the graph's nodes see them.
NAME = r"/?[A-Za-z][A-Za-z0-9_]*(?:/[A-Za-z][A-Za-z0-9_]*)*"
RATE = re.compile(r"\s*([0-9]+(?:\.[0-9]*)?|\.[0-9]+)\s*(?:Hz)?\s*", re.ASCII)
MAX_RATE = 10_000

_name = c.string(NAME, "a ROS graph name like /chatter or /front/scan")


def rate(value) -> float | None:
    """Hz from ``2``, ``2.5`` or ``"2 Hz"``; None when it is none of them."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value)
    found = RATE.fullmatch(value) if isinstance(value, str) else None
    return float(found.group(1)) if found else None


def _rate(value):
    hz = rate(value)
    if hz is None:
        return [("", f"expected a rate like 2 Hz, got {c.describe(value)}")]
    if not 0 < hz <= MAX_RATE:
        return [("", f"expected a rate above 0 Hz and at most {MAX_RATE} Hz, got {c.describe(value)}")]
    return []


c.with_schema(
    _rate,
    {
        "anyOf": [
            {"type": "number", "exclusiveMinimum": 0, "maximum": MAX_RATE},
            {"type": "string", "pattern": "^\\s*[0-9.]+\\s*(?:Hz)?\\s*$"},
        ],
        "description": "the minimum rate, in Hz: 2 or '2 Hz'",
    },
)
_parts = {
    "nodes": c.list_of(_name, unique=True),
    "topics": c.mapping_of(_name, _rate),
    "services": c.list_of(_name, unique=True),
}


def check(value):
    if not isinstance(value, dict):
        return [("", f"expected a mapping of {', '.join(KEYS)}, got {c.describe(value)}")]
    found = []
    for key, given in value.items():
        if key not in _parts:
            found.append((f".{c.key_name(key)}", f"not a key of ros_health{c.did_you_mean(str(key), KEYS)}"))
        else:
            found += [(f".{key}{sub}", message) for sub, message in _parts[key](given)]
    return found


c.with_schema(
    check,
    {
        "type": "object",
        "description": "what a healthy release's ROS 1 graph shows (checked from inside roscore)",
        "properties": {key: part.schema for key, part in _parts.items()},
        "additionalProperties": False,
    },
)


def problems(data) -> list[c.Problem]:
    """Across settings: the probe runs in the project's roscore."""
    if not value_of(data, SETTING):
        return []
    if value_of(data, "ros_preset") != "ros1" or not value_of(data, "ros_roscore"):
        return [
            (
                SETTING,
                "needs ros_preset: ros1 and ros_roscore: true (the graph is read from inside the project's roscore)",
            )
        ]
    return []


def global_name(name: str) -> str:
    return name if name.startswith("/") else "/" + name


def top_level(data) -> dict:
    """The compose document's ``x-ros-health`` (global names, Hz), or {}."""
    declared = value_of(data, SETTING)
    if not declared:
        return {}
    wanted = {
        "nodes": [global_name(n) for n in declared.get("nodes") or ()],
        "topics": {global_name(t): rate(r) for t, r in (declared.get("topics") or {}).items()},
        "services": [global_name(s) for s in declared.get("services") or ()],
    }
    return {KEY: {key: value for key, value in wanted.items() if value}}
