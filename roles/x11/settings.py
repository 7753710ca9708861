"""The x11 role's settings."""

from __future__ import annotations

from robotfleet import checkers as c
from robotfleet import value_kinds as v
from robotfleet.role import Renamed, Setting

SETTINGS = (
    Setting(
        "x11_enabled", False, c.boolean, "The host has a display for GUI containers (rviz).", groups={"laptops": True}
    ),
    Setting("x11_user", None, c.optional(v.user_name), "The desktop user whose X session the containers use."),
    Setting(
        "x11_display",
        ":0",
        c.string(r"(?:[A-Za-z0-9.-]*):[0-9]+(?:\.[0-9]+)?", "an X display like :0"),
        "The X display containers connect to.",
    ),
    Setting(
        "x11_cookie_dir",
        "/var/lib/robot-x11",
        v.private_path,
        "Per-user cookie directories (<dir>/<user>/Xauthority), mounted read-only.",
    ),
)
RENAMED = (Renamed("display", "x11_enabled"),)


def rules(data: dict, refused: frozenset) -> list[c.Problem]:
    if data.get("x11_enabled") is True and not {"x11_enabled", "x11_user"} & refused and not data.get("x11_user"):
        return [("x11_user", "required when x11_enabled is true: the desktop user")]
    return []
