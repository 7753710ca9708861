"""The udev role's settings: sensors and the rules files."""

from __future__ import annotations

from robotfleet import checkers as c
from robotfleet import value_kinds as v
from robotfleet.role import Renamed, Setting

SUBSYSTEMS = ("tty", "video4linux", "hidraw", "input", "usb", "sound")
DEFAULT_SENSOR_GROUP = {
    "tty": "dialout",
    "video4linux": "video",
    "sound": "audio",
    "input": "input",
}
USB_PORT = r"[0-9]+-[0-9]+(?:\.[0-9]+)*(?::[0-9]+\.[0-9]+)?"
# udev match values are quoted strings: keep them to characters that need no
# escaping, so a value can never end the rule or inject a key.
UDEV_VALUE = r"[A-Za-z0-9._:/+ -]{1,126}"
MODE = r"0?[0-7]{3}"
SYMLINK = r"[A-Za-z0-9_][A-Za-z0-9_.-]*(?:/[A-Za-z0-9_][A-Za-z0-9_.-]*)*"

SENSOR_FIELDS = {
    "name": c.string(c.IDENTIFIER, "a name of lowercase letters, digits, - and _"),
    "subsystem": c.string(choices=SUBSYSTEMS),
    "serial": c.string(UDEV_VALUE, "a serial of letters, digits and . _ : / + -"),
    "vendor_id": c.string(c.HEX4, "a 4-digit hex USB vendor id"),
    "product_id": c.string(c.HEX4, "a 4-digit hex USB product id"),
    "usb_port": c.string(USB_PORT, "a USB port path like 1-2.1"),
    "group": c.string(c.USER_NAME, "a group name"),
    "mode": c.string(MODE, 'an octal mode like "0660"'),
    "symlink": c.string(SYMLINK, "a path relative to /dev like robot/front_camera"),
    "passthrough": c.boolean,
    # The payload's compose services that get the device (default: those
    # that ask for devices, or the one service).
    "services": c.list_of(c.string(r"[a-zA-Z0-9][a-zA-Z0-9._-]*", "a service name"), unique=True),
}
SENSOR_KEYS = tuple(SENSOR_FIELDS)


def sensor(value):
    if not isinstance(value, dict):
        return [("", f"expected a mapping with at least name and subsystem, got {c.describe(value)}")]
    problems = []
    for key in value:
        if not isinstance(key, str):
            problems.append(
                (f".{c.key_name(key)}", f"a sensor field name must be a string, got {c.describe(key)}; quote it")
            )
        elif key not in SENSOR_KEYS:
            problems.append((f".{c.key_name(key)}", "unknown sensor field" + c.did_you_mean(key, SENSOR_KEYS)))
    for key in ("name", "subsystem"):
        if key not in value:
            problems.append((f".{key}", "required"))
    for key, check in SENSOR_FIELDS.items():
        if key in value:
            problems += [(f".{key}{sub}", msg) for sub, msg in check(value[key])]
    if ("vendor_id" in value) != ("product_id" in value):
        missing = "product_id" if "vendor_id" in value else "vendor_id"
        problems.append((f".{missing}", "vendor_id and product_id go together"))
    if not any(k in value for k in ("serial", "vendor_id", "usb_port")):
        problems.append(("", "needs a match: serial, vendor_id/product_id or usb_port"))
    return problems


c.with_schema(
    sensor,
    {
        "type": "object",
        "properties": {key: check.schema for key, check in SENSOR_FIELDS.items()},
        "required": ["name", "subsystem"],
        "anyOf": [{"required": [key]} for key in ("serial", "vendor_id", "usb_port")],
        "additionalProperties": False,
    },
)


def udev_rules_path(value):
    problems = v.abs_path(value)
    if not problems and not (value.startswith("/etc/udev/rules.d/") and value.endswith(".rules")):
        return [("", f"expected a file in /etc/udev/rules.d/ ending in .rules, got {c.shown(value)}")]
    return problems


c.with_schema(udev_rules_path, {"type": "string", "pattern": "^/etc/udev/rules\\.d/[A-Za-z0-9._@+-]+\\.rules$"})

SETTINGS = (
    Setting(
        "udev_sensors",
        [],
        c.list_of(sensor),
        "Sensors given stable names under /dev (see README, Describing a fleet: name, subsystem, a match).",
    ),
    Setting(
        "udev_rules_file", "/etc/udev/rules.d/70-robot-sensors.rules", udev_rules_path, "The generated rules file."
    ),
    Setting(
        "udev_vendor_rules",
        [],
        c.list_of(c.string(r"[A-Za-z0-9_.-]+\.rules", "a file name in files/udev/ ending in .rules"), unique=True),
        "Static rules files from files/udev/ installed on the host.",
        groups={"robots": ["60-usb-serial-low-latency.rules"]},
    ),
    Setting("udev_allow_world_writable", False, c.boolean, "Allow world-writable device modes (refused otherwise)."),
)

RENAMED = (Renamed("sensors", "udev_sensors"),)


# What a sensor's rule matches a device by (robotfleet's udev rules: roles/udev/rules.py).
MATCH_KEYS = ("subsystem", "serial", "vendor_id", "product_id", "usb_port")


def overlapping(this: tuple[str, dict], other: tuple[str, dict]) -> str | None:
    """How two sensors (name as shown, match) can select one device, or None: one's
    match keys are a part of the other's with the same values, so that every
    device the narrower one matches, the wider one matches too."""
    (name, match), (other_name, other_match) = this, other
    if match == other_match:
        return f"{name} matches the same devices as {other_name}"
    for wide, wide_match, narrow, narrow_match in (
        (name, match, other_name, other_match),
        (other_name, other_match, name, match),
    ):
        if wide_match.items() <= narrow_match.items():
            keys = ", ".join(wide_match)
            return f"{wide} also matches the devices of {narrow}: its match ({keys}) is a part of the other's"
    return None


def rules(data: dict, refused: frozenset) -> list[c.Problem]:
    """Rules across sensors, over the sensors that are valid on their own."""
    sensors = data.get("udev_sensors")
    if not isinstance(sensors, list):
        return []
    # A refused list still has sensors that are valid on their own.
    valid = [(i, s) for i, s in enumerate(sensors) if "udev_sensors" not in refused or not sensor(s)]
    allow_world_writable = data.get("udev_allow_world_writable") is True  # a refused value allows nothing
    problems = []
    names, links, matches = {}, {}, {}
    for index, item in valid:
        where = f"udev_sensors[{index}]"
        name = item["name"]
        if name in names:
            problems.append((f"{where}.name", f"duplicate sensor name {name!r} (also udev_sensors[{names[name]}])"))
        names.setdefault(name, index)
        link = item.get("symlink") or f"robot/{name}"
        if link in links:
            problems.append((f"{where}.symlink", f"/dev/{link} is already used by udev_sensors[{links[link]}]"))
        links.setdefault(link, index)
        match = {k: item[k] for k in MATCH_KEYS if k in item}
        for other, (other_name, other_match) in matches.items():
            overlap = overlapping((name, match), (f"{other_name} (udev_sensors[{other}])", other_match))
            if overlap:
                problems.append((where, f"{overlap}; add a serial or usb_port to tell them apart"))
                break
        matches[index] = (name, match)
        mode = item.get("mode")
        if mode is not None and int(mode, 8) & 0o002 and not allow_world_writable:
            problems.append(
                (f"{where}.mode", f"{mode} is world-writable; use a group (or set udev_allow_world_writable)")
            )
    return problems
