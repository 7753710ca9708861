"""``ros_health``: what a healthy release of a ROS 1 graph publishes (nodes
up, topics at a minimum rate, services that answer), checked in the fleet
file and turned into the release's graph check, which payloadctl runs in
the roscore container once the containers are healthy (payloadctl/graph.py)."""

from __future__ import annotations

import re

from robotfleet import checkers as c
from roles.payload.presets import ROSCORE
from roles.payload.services import value_of

SETTING = "ros_health"
# A global ROS graph resource name: /token/token..., each token a letter then letters, digits, underscores.
NAME = r"(/[A-Za-z][A-Za-z0-9_]*)+"
RATE = re.compile(r"([0-9]+(?:\.[0-9]+)?)\s*Hz", re.ASCII)
KEYS = ("nodes", "topics", "services")

graph_name = c.string(NAME, "a global ROS graph name (/talker, /scan/front)")


def rate_hz(value) -> float | None:
    """``2``, ``2.5`` or ``"2 Hz"`` as a rate in Hz; None when it is none of them."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value)
    found = RATE.fullmatch(value.strip()) if isinstance(value, str) else None
    return float(found.group(1)) if found else None


def rate(value) -> list[c.Problem]:
    found = rate_hz(value)
    if found is None:
        return [("", f"expected a rate such as 2 Hz, got {c.describe(value)}")]
    if found <= 0:
        return [("", f"expected a rate above 0 Hz, got {c.describe(value)}")]
    return []


rate.schema = {"anyOf": [{"type": "number", "exclusiveMinimum": 0}, {"type": "string", "pattern": RATE.pattern}]}

_parts = {
    "nodes": c.list_of(graph_name, unique=True),
    "topics": c.mapping_of(graph_name, rate),
    "services": c.list_of(graph_name, unique=True),
}


def check(value) -> list[c.Problem]:
    if value is None:
        return []
    if not isinstance(value, dict):
        return [("", f"expected a mapping of nodes, topics and services, got {c.describe(value)}")]
    problems = []
    for key, item in value.items():
        if key not in _parts:
            problems.append((f".{c.key_name(key)}", f"unknown key; expected one of {', '.join(KEYS)}"))
        else:
            problems += [(f".{key}{sub}", why) for sub, why in _parts[key](item)]
    return problems


check.schema = {
    "anyOf": [
        {"type": "object", "properties": {k: v.schema for k, v in _parts.items()}, "additionalProperties": False},
        {"type": "null"},
    ]
}


def problems(data) -> list[c.Problem]:
    """ros_health reads the graph from the project's own roscore."""
    if not value_of(data, SETTING):
        return []
    if value_of(data, "ros_preset") != "ros1" or not value_of(data, "ros_roscore"):
        return [
            (SETTING, "needs ros_preset: ros1 and ros_roscore: true (the graph is read from the project's roscore)")
        ]
    return []


def graph_check(data) -> dict | None:
    """The release's graph check (spec ``checks``), or None without ros_health."""
    health = value_of(data, SETTING)
    if not health:
        return None
    return {
        "graph": {
            "service": ROSCORE,
            "nodes": list(health.get("nodes") or ()),
            "topics": {name: rate_hz(value) for name, value in (health.get("topics") or {}).items()},
            "services": list(health.get("services") or ()),
            "wait": value_of(data, "payload_health_timeout"),
        },
        "failure": "ROS graph is not healthy (ros_health)",
    }
