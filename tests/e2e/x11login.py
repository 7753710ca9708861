"""A graphical login on a lab laptop, as test_x11 and test_rviz start one."""

from __future__ import annotations

import time


def login(lab, laptop: str) -> None:
    """A graphical login of alice: startx runs the X server with a fresh
    cookie and Xsession runs the session hooks, ours included."""
    # The last session's processes die after pkill returns: until they are gone, its
    # `sleep` would pass for the new session's (which then has not written its cookie).
    lab.ok(
        laptop,
        "pkill -u alice -f xinit; pkill -u alice -x Xvfb; pkill -u alice -x sleep; "
        "for i in $(seq 100); do pgrep -u alice -f 'xinit|Xvfb|sleep' >/dev/null || break; sleep 0.1; done; "
        "! pgrep -u alice -f 'xinit|Xvfb|sleep' && rm -f /tmp/.X0-lock",
    )
    lab.ok(
        laptop,
        "su - alice -c 'nohup startx /etc/X11/Xsession /usr/local/bin/lab-session -- "
        "/usr/bin/Xvfb :0 -screen 0 1024x768x24 > /tmp/startx.log 2>&1 &'",
    )
    for _ in range(30):
        if lab.sh(laptop, "pgrep -u alice -x sleep")[0] == 0:
            return
        time.sleep(0.5)
    raise AssertionError(lab.sh(laptop, "cat /tmp/startx.log")[1])
