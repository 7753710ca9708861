"""Test fixtures: what a successful run of the x11 role leaves on a host."""

from robotfleet.host.fixtures import file_state
from robotfleet.host.snapshot import FileState
from roles import x11


def converged(play, host: str) -> None:
    data, snap = play.data, play.snapshot
    user = data.x11_user
    groups = snap.users.setdefault(user, [user, "docker"])
    snap.packages["xauth"] = "1"
    snap.files.update(
        {
            x11.COOKIE_SCRIPT: file_state(x11.cookie_script(data), "755"),
            x11.XSESSION_HOOK: file_state((x11.HERE / "90robot-x11-cookie").read_text()),
            x11.AUTOSTART: file_state((x11.HERE / "robot-x11-cookie.desktop").read_text()),
            data.x11_cookie_dir: FileState("dir", None, "755", "root", "root"),
            x11.cookie_dir(data): FileState("dir", None, "700", user, groups[0]),
        }
    )
