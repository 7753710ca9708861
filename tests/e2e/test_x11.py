"""X11 on the laptop for real: an X server (Xvfb) started by a login
(startx -> Xsession), the cookie the login hook writes, and a container
started the way the payload is started opening the display with it."""

from __future__ import annotations

import pytest

from tests.e2e.x11login import login

pytestmark = pytest.mark.e2e

COMPOSE = "/var/lib/robot-payload/current/compose.yaml"
# The probe: xdpyinfo and exactly the libraries it links, imported as an
# image on the laptop (no registry needed), run with the payload's compose
# settings (X socket, cookie directory, DISPLAY, XAUTHORITY, host network).
BUILD_PROBE = """
set -e
rm -rf /tmp/probe && mkdir -p /tmp/probe
for f in /usr/bin/xdpyinfo $(ldd /usr/bin/xdpyinfo | grep -o '/[^ ]*'); do cp -L --parents "$f" /tmp/probe/; done
tar -C /tmp/probe -c . | docker import - lab/x11probe:1 >/dev/null
printf 'services:\\n  payload:\\n    image: lab/x11probe:1\\n    command: ["/usr/bin/xdpyinfo"]\\n' > /tmp/probe.yaml
"""
PROBE = f"docker compose -p x11probe -f {COMPOSE} -f /tmp/probe.yaml run --rm --no-deps"


@pytest.fixture(scope="module")
def desktop(lab, first_run):
    laptop = lab.laptops[0]
    lab.ok(
        laptop,
        "DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends xvfb xinit x11-utils "
        "x11-xserver-utils",
    )
    lab.ok(laptop, BUILD_PROBE)
    lab.ok(
        laptop,
        "printf '#!/bin/sh\\nexec sleep infinity\\n' > /usr/local/bin/lab-session && chmod 755 "
        "/usr/local/bin/lab-session",
    )
    yield laptop
    lab.sh(laptop, "pkill -u alice -f xinit; pkill -u alice Xvfb; true")


def test_login_writes_a_private_cookie_and_containers_can_use_it(lab, desktop):
    laptop = desktop
    lab.ok(laptop, "rm -f /var/lib/robot-x11/alice/Xauthority")
    login(lab, laptop)
    assert lab.ok(laptop, "stat -c '%a %U' /var/lib/robot-x11/alice /var/lib/robot-x11/alice/Xauthority").split() == [
        "700",
        "alice",
        "600",
        "alice",
    ]
    # The cookie's address family is "wild" (ffff), valid from any container host name.
    assert lab.ok(laptop, "xauth -f /var/lib/robot-x11/alice/Xauthority nlist").startswith("ffff")
    output = lab.ok(laptop, f"{PROBE} payload")
    assert "name of display:    :0" in output and "X.Org" in output


def test_a_container_without_the_cookie_is_refused(lab, desktop):
    login(lab, desktop)
    code, output = lab.sh(desktop, f"{PROBE} -e XAUTHORITY=/nonexistent payload")
    assert code != 0 and 'unable to open display ":0"' in output


def test_a_new_login_refreshes_the_cookie_for_running_containers(lab, desktop):
    login(lab, desktop)
    first = lab.ok(desktop, "sha256sum /var/lib/robot-x11/alice/Xauthority")
    login(lab, desktop)  # a new X session: a new cookie
    assert lab.ok(desktop, "sha256sum /var/lib/robot-x11/alice/Xauthority") != first
    assert "name of display:    :0" in lab.ok(desktop, f"{PROBE} payload")


def test_nobody_opened_the_display_to_everyone(lab, desktop):
    login(lab, desktop)
    listing = lab.ok(desktop, "su - alice -c 'DISPLAY=:0 xhost'")
    assert "access control enabled" in listing
