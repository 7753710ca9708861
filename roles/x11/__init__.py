"""roles/x11: X11 access for GUI containers (rviz) with an xauth cookie.

At each login of the desktop user a hook writes a container-usable cookie to
<x11_cookie_dir>/<user>/Xauthority (directory 0700, file 0600); the payload
mounts the directory read-only with XAUTHORITY set.  Never `xhost +`.
"""

from __future__ import annotations

import functools
from pathlib import Path

import jinja2
from pyinfra.api import deploy

import roles.payload.hooks as payload_hooks
from robotfleet.host import apt, operations
from robotfleet.host.snapshot import SnapshotQuery
from robotfleet.role import Play, Role
from roles.x11 import settings

HERE = Path(__file__).resolve().parent
COOKIE_SCRIPT = "/usr/local/bin/robot-x11-cookie"
XSESSION_HOOK = "/etc/X11/Xsession.d/90robot-x11-cookie"
AUTOSTART = "/etc/xdg/autostart/robot-x11-cookie.desktop"
CONTAINER_DIR = "/tmp/.robot-x11"


def cookie_dir(data) -> str:
    return f"{data.x11_cookie_dir}/{data.x11_user}"


@functools.lru_cache(maxsize=1)
def _cookie_template() -> jinja2.Template:
    return jinja2.Template((HERE / "robot-x11-cookie.sh.j2").read_text(), keep_trailing_newline=True)


def cookie_script(data) -> str:
    return _cookie_template().render(cookie_dir=data.x11_cookie_dir)


def compose_settings(data) -> dict:
    """What a GUI container needs: the X socket, the cookie, and DISPLAY."""
    return {
        "environment": {
            "DISPLAY": data.x11_display,
            "XAUTHORITY": f"{CONTAINER_DIR}/Xauthority",
            "QT_X11_NO_MITSHM": "1",
        },
        "volumes": [
            "/tmp/.X11-unix:/tmp/.X11-unix:ro",
            f"{cookie_dir(data)}:{CONTAINER_DIR}:ro",
        ],
    }


def payload_services(data, services: dict) -> dict:
    """The payload hook: where the host has a display, every service gets it."""
    return {"*": compose_settings(data)} if data.get("x11_enabled") else {}


def declare_reads(data, query: SnapshotQuery) -> None:
    query.packages.add("xauth")
    query.files |= {COOKIE_SCRIPT, XSESSION_HOOK, AUTOSTART, data.x11_cookie_dir, cookie_dir(data)}
    query.users.add(data.x11_user)


@deploy("X11")
def x11_cookie(play: Play):
    data, snap = play.data, play.snapshot
    groups = snap.users.get(data.x11_user)
    if groups is None:
        operations.fail(
            name="Check the desktop user",
            message=f"x11_user: {data.x11_user} does not exist on this host",
        )
        return
    apt.apt_install(name="Install xauth", packages=["xauth"], installed=snap.packages)
    operations.file(
        name="Install the cookie script",
        path=COOKIE_SCRIPT,
        content=cookie_script(data),
        current=snap.files.get(COOKIE_SCRIPT),
        mode="0755",
    )
    operations.file(
        name="Refresh the cookie at each X session start (Xsession.d hook)",
        path=XSESSION_HOOK,
        content=(HERE / "90robot-x11-cookie").read_text(),
        current=snap.files.get(XSESSION_HOOK),
    )
    operations.file(
        name="Refresh the cookie at each desktop login (XDG autostart)",
        path=AUTOSTART,
        content=(HERE / "robot-x11-cookie.desktop").read_text(),
        current=snap.files.get(AUTOSTART),
    )
    operations.directory(
        name=f"Cookie directories root {data.x11_cookie_dir}",
        path=data.x11_cookie_dir,
        current=snap.files.get(data.x11_cookie_dir),
    )
    operations.directory(
        name=f"Cookie directory of {data.x11_user}",
        path=cookie_dir(data),
        current=snap.files.get(cookie_dir(data)),
        mode="0700",
        user=data.x11_user,
        group=groups[0],
    )


ROLE = Role(
    name="x11",
    doc="X11 access for GUI containers (rviz) with an xauth cookie refreshed at each login; never xhost +.",
    settings=settings.SETTINGS,
    runs_on=lambda data: bool(data.x11_enabled),
    reads=declare_reads,
    steps=x11_cookie,
    rules=settings.rules,
    renamed=settings.RENAMED,
    adds={payload_hooks.SERVICES: payload_services},
)
