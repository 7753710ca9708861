"""Render sensor udev rules and lint rules files (pure)."""

from __future__ import annotations

import re

from roles.udev.settings import DEFAULT_SENSOR_GROUP

HEADER = (
    "# Managed by the robot fleet provisioner (roles/udev) from the fleet file's\n"
    "# `udev_sensors`; local edits are overwritten.\n"
)
# Only the first node of a V4L device (index 0) is the capture node; the
# others are metadata nodes that must not steal the name.
SUBSYSTEM_MATCH = {
    "tty": ['SUBSYSTEM=="tty"'],
    "video4linux": ['SUBSYSTEM=="video4linux"', 'ATTR{index}=="0"'],
    "hidraw": ['SUBSYSTEM=="hidraw"'],
    "input": ['SUBSYSTEM=="input"', 'KERNEL=="event*"'],
    "usb": ['SUBSYSTEM=="usb"', 'ENV{DEVTYPE}=="usb_device"'],
    "sound": ['SUBSYSTEM=="sound"', 'KERNEL=="controlC*"'],
}


def symlink(sensor: dict) -> str:
    return sensor.get("symlink") or f"robot/{sensor['name']}"


def rule(sensor: dict) -> str:
    matches = ['ACTION!="remove"'] + SUBSYSTEM_MATCH[sensor["subsystem"]]
    if "usb_port" in sensor:
        matches.append(f'KERNELS=="{sensor["usb_port"]}"')
    if "vendor_id" in sensor:
        matches.append(f'ATTRS{{idVendor}}=="{sensor["vendor_id"].lower()}"')
        matches.append(f'ATTRS{{idProduct}}=="{sensor["product_id"].lower()}"')
    if "serial" in sensor:
        matches.append(f'ATTRS{{serial}}=="{sensor["serial"]}"')
    group = sensor.get("group") or DEFAULT_SENSOR_GROUP.get(sensor["subsystem"], "plugdev")
    mode = sensor.get("mode") or "0660"
    if len(mode) == 3:
        mode = "0" + mode
    actions = [f'SYMLINK+="{symlink(sensor)}"', f'GROUP="{group}"', f'MODE="{mode}"']
    return ", ".join(matches + actions)


def render(sensors: list[dict]) -> str:
    lines = [HEADER]
    for sensor in sensors:
        how = ", ".join(f"{k}={sensor[k]}" for k in ("serial", "vendor_id", "product_id", "usb_port") if k in sensor)
        lines.append(f"# {sensor['name']}: {sensor['subsystem']} by {how}\n{rule(sensor)}\n")
    return "\n".join(lines)


def devices(sensors: list[dict]) -> list[str]:
    """Device paths handed to the payload container."""
    return [f"/dev/{symlink(s)}" for s in sensors if s.get("passthrough", True)]


_TOKEN = re.compile(
    r'\s*(?P<key>[A-Z_]+)(?:\{(?P<attr>[^}"]*)\})?\s*(?P<op>==|!=|\+=|-=|:=|=)\s*"(?P<value>(?:[^"\\]|\\.)*)"\s*'
)
KNOWN_KEYS = {
    "ACTION",
    "DEVPATH",
    "KERNEL",
    "KERNELS",
    "NAME",
    "SYMLINK",
    "SUBSYSTEM",
    "SUBSYSTEMS",
    "DRIVER",
    "DRIVERS",
    "ATTR",
    "ATTRS",
    "SYSCTL",
    "TAG",
    "TAGS",
    "ENV",
    "CONST",
    "TEST",
    "PROGRAM",
    "RESULT",
    "OWNER",
    "GROUP",
    "MODE",
    "SECLABEL",
    "RUN",
    "LABEL",
    "GOTO",
    "IMPORT",
    "OPTIONS",
}


def lint(text: str, allow_world_writable: bool = False) -> list[str]:
    """Syntax problems in a rules file, as 'line N: message' (empty if fine).
    A cheap check that needs no udevadm; hosts with udevadm verify run it too."""
    problems = []
    logical, start = "", 0
    for number, raw in enumerate(text.splitlines(), 1):
        if not logical:
            start = number
        line = raw.rstrip()
        if line.endswith("\\"):
            logical += line[:-1] + " "
            continue
        logical += line
        stripped = logical.strip()
        logical = ""
        if not stripped or stripped.startswith("#"):
            continue
        for item in _split_items(stripped):
            match = _TOKEN.fullmatch(item)
            if not match:
                problems.append(f"line {start}: cannot parse {item.strip()!r}")
            elif match.group("key") not in KNOWN_KEYS:
                problems.append(f"line {start}: unknown key {match.group('key')}")
            elif match.group("key") == "MODE" and not allow_world_writable and _world_writable(match.group("value")):
                problems.append(f"line {start}: MODE {match.group('value')} is world-writable")
    return problems


def _world_writable(value: str) -> bool:
    return bool(re.fullmatch(r"0?[0-7]{3}", value)) and bool(int(value, 8) & 0o002)


def _split_items(line: str) -> list[str]:
    items, current, quoted, escaped = [], "", False, False
    for char in line:
        if char == "," and not quoted:
            items.append(current)
            current = ""
            continue
        if char == '"' and not escaped:
            quoted = not quoted
        escaped = char == "\\" and not escaped
        current += char
    items.append(current)
    return [i for i in items if i.strip()]


def subsystems(text: str) -> set[str]:
    """Subsystems a rules file acts on: what to trigger after a change (a
    bare `udevadm trigger` would replay every device and fails where /sys is
    read-only)."""
    return set(re.findall(r'SUBSYSTEMS?=="([a-z0-9_-]+)"', text))
