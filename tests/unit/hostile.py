"""Hostile values, the YAML traps of an unquoted fleet file and every place
of a setting a string can go: what tests/unit/test_hostile_values.py and
test_schema_agreement.py put in every setting."""

from __future__ import annotations

from roles.udev.settings import SENSOR_KEYS

HOSTILE = [
    "$(touch /tmp/x)",
    "`id`",
    "a;b",
    "a|b",
    "a&b",
    "a'b",
    'a"b',
    "a\nb",
    "a\rb",
    "a b",
    "${X:?}",
    "s3cr$et",
    "..",
    "../../etc",
    "/var/lib/../../tmp",
    "/tmp",
    "/var/tmp/x",
    "-rf",
    "--help",
    "a\\b",
    "a#b",
    "*",
    "~root",
    "\u0430dmin",  # Cyrillic a
    "r\u043ebot",  # Cyrillic o
    "v\uff11",  # fullwidth digit one
    "x\u202ey",  # right-to-left override
    "a\u00a0b",  # no-break space
    "\x00",
    "a\x1bb",
]
# YAML traps, written unquoted in the fleet file (YAML 1.2: these are not text).
YAML_TRAPS = ["true", "False", "1.10", "0755", "0x1F", "1e3", "~"]


def places(name: str, value):
    """Every place in setting ``name`` where a string can go."""
    yield "value", value
    yield "list item", [value]
    yield "mapping key", {value: "x"}
    yield "mapping value", {"X": value}
    # Inside otherwise valid URLs, paths and image references.
    for place, text in (
        ("in a URL", f"https://mirror.lan/gpg?x={value}"),
        ("in a path", f"/var/lib/{value}"),
        ("in an image tag", f"reg.example.com/p:{value}"),
    ):
        yield place, text
        yield f"{place}, list item", [text]
    if name == "udev_sensors":
        for field in SENSOR_KEYS:
            sensor = {"name": "a", "subsystem": "tty", "serial": "1", field: value}
            if field in ("vendor_id", "product_id"):  # the pair rule is not what is tested here
                sensor = {"vendor_id": "046d", "product_id": "0825", **sensor}
            yield field, [sensor]
    if name == "docker_daemon_options":
        yield "log-opts value", {"log-opts": {"max-size": value}}
        yield "dns item", {"dns": [value]}
        yield "features key", {"features": {value: True}}
        yield "builder value", {"builder": {"x": value}}
