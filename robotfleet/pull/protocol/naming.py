"""How a robot started from an image shared by many robots names itself
(a first-boot bundle made with ``robotfleet bundle --name-from``).

The name is the bundle's prefix and the robot's own identity:

- ``machine-id``: the first 12 hex digits of /etc/machine-id (systemd makes
  it at first boot when the image ships it empty: every robot gets its own);
  48 bits, so 10,000 robots collide with odds of about 1 in 5 million;
- ``dmi-serial``: the board's serial number (/sys/class/dmi/id/product_serial,
  root's only), lowercased, each character a name cannot hold made ``-``;
  placeholders vendors leave ("To Be Filled By O.E.M.", "Default string",
  "0123456789", ...) are refused: every robot would take the same name.

The same robot always derives the same name, so it is derived at each
check.  The result must be a robot name (and a gitolite user): letters,
digits, ``-``, ``.``, ``_``, ``+``, starting with a letter or digit.
"""

from __future__ import annotations

import re

RULES = {"machine-id": "/etc/machine-id", "dmi-serial": "/sys/class/dmi/id/product_serial"}
PREFIX = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]{0,63}\Z")
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]{0,252}\Z")
MACHINE_ID = re.compile(r"[0-9a-f]{32}\Z")
# What a name derived by each rule looks like after the prefix (gitolite's refex for a shared enrollment key).
PATTERNS = {"machine-id": "[0-9a-f]{12}", "dmi-serial": "[a-z0-9._+-]+"}
PLACEHOLDERS = {
    "",
    "0",
    "none",
    "null",
    "n/a",
    "na",
    "default string",
    "to be filled by o.e.m.",
    "not specified",
    "system serial number",
    "chassis serial number",
    "123456789",
    "0123456789",
    "1234567890",
    "not applicable",
    "unknown",
    "oem",
    "o.e.m.",
}


class NamingError(ValueError):
    """The robot cannot derive its name (one line)."""


def check_rule(rule: str, prefix: str) -> None:
    if rule not in RULES:
        raise NamingError(f"name rule {rule!r}: expected one of {', '.join(RULES)}")
    if not PREFIX.match(prefix):
        raise NamingError(
            f"name prefix {prefix!r}: expected letters, digits, '-', '.', '_', '+' "
            "(starting with a letter or digit, at most 64)"
        )


def derive(rule: str, prefix: str, raw: str) -> str:
    """The robot's name from ``raw``, the text of the rule's source (pure)."""
    check_rule(rule, prefix)
    text = raw.strip()
    if rule == "machine-id":
        if not MACHINE_ID.match(text):
            raise NamingError(
                f"{RULES[rule]}: expected 32 lowercase hex digits, got {text[:40]!r} "
                "(an image must ship it empty, so that each robot makes its own)"
            )
        return prefix + text[:12]
    if text.lower() in PLACEHOLDERS or len(set(text.lower())) == 1:
        raise NamingError(
            f"{RULES[rule]}: {text[:40]!r} is a placeholder, not this board's serial: "
            "every robot would take the same name (use --name-from machine-id)"
        )
    name = prefix + re.sub(r"[^a-z0-9._+-]", "-", text.lower())
    if not NAME.match(name):
        raise NamingError(f"{RULES[rule]}: {text[:40]!r} makes no robot name")
    return name


def read(rule: str) -> str:
    """The text of the rule's source on this robot."""
    try:
        with open(RULES[rule], encoding="utf-8", errors="replace") as handle:
            return handle.read(512)
    except OSError as error:
        raise NamingError(f"{RULES[rule]}: cannot be read ({error.strerror})") from None
