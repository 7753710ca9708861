"""rviz on a laptop for real (docs/guides/ros-payload.md, "rviz on a
laptop"): the guide's laptop entry, Debian bookworm's rviz 1.14 (Noetic's)
in the laptop's payload image (tests/lab/ros_images.py, ros/noetic-rviz),
deployed with the guide's ROS graph on robot2 in one run, started through
the payload's compose file as the guide says, drawing with the X11 cookie
the x11 role writes (no `xhost +`) on the laptop's X server (Xvfb, started
by a login as in test_x11.py) with Mesa's software renderer, in robot2's
graph.  It leaves robot2 on the graph and the laptop on rviz (its session's
lab is its own).

Costly: the rviz image (493 MB) is built once per machine and pushed to the
lab's registry, the laptop pulls it.  Not in the test command: it runs on
demand (tests/e2e/groups.py ON_DEMAND; docs/guides/development.md)."""

from __future__ import annotations

import io
import os
import tarfile
import time

import pytest
import yaml

from tests.e2e.conftest import ROOT, phase, wait_for
from tests.e2e.x11login import login
from tests.lab import ros_graph, ros_images, xwd
from tests.lab.engine import client

pytestmark = [pytest.mark.e2e, pytest.mark.rviz]

LAPTOP, ROBOT = "laptop1", "robot2"
COMPOSE = "/var/lib/robot-payload/current/compose.yaml"
ROSCORE = "robot-payload-roscore-1"
GUIDE_MARKER = "<!-- the rviz laptop test_rviz.py deploys -->"
X = "DISPLAY=:0 XAUTHORITY=/var/lib/robot-x11/alice/Xauthority"
# Not under /tmp: systemd mounts a tmpfs there, which the engine's archive API does not see.
SHOT = "/var/tmp/rviz-shot.xwd"
# rviz's default 3D view: background (48, 48, 48), the grid's lines (160, 160, 164) at alpha 0.5 over it.
BACKGROUND, GRID = (48, 48, 48), (104, 104, 106)
# Where the docs' picture comes from: ROBOT_LAB_RVIZ_SCREENSHOT=docs/images/rviz-on-a-laptop.png
SCREENSHOT_ENV = "ROBOT_LAB_RVIZ_SCREENSHOT"


def laptop_vars(prefix: str) -> dict:
    """The guide's laptop entry as the lab's laptop takes it: the lab's registry, and the hosts'
    names on the lab's network (its docker network resolves container names, <prefix>-<host>)."""
    text = ros_graph.GUIDE.read_text()
    block = text[text.index(GUIDE_MARKER) :].split("```yaml\n", 1)[1].split("```", 1)[0]
    found = yaml.safe_load(block)["laptops"]["hosts"][LAPTOP]
    assert found.pop("x11_user") == "alice"  # as inventories/lab.yaml has it already
    found["payload_image"] = found["payload_image"].replace(ros_graph.GUIDE_REGISTRY, "@registry@/")
    assert found["ros_master_uri"] == f"http://{ROBOT}:11311" and found["ros_hostname"] == LAPTOP
    found["ros_master_uri"] = f"http://{prefix}-{ROBOT}:11311"
    found["ros_hostname"] = f"{prefix}-{LAPTOP}"
    return {**found, "ros_domain_id": 0}  # inventories/lab.yaml gives every host 7 (ROS 2's)


def fleet_text(prefix: str) -> str:
    """inventories/lab.yaml with the guide's graph on robot2 (named as the laptop reaches it) and rviz on laptop1."""
    text = ros_graph.lab_fleet({ROBOT: {"ros_hostname": f"{prefix}-{ROBOT}"}})
    anchor = f"    {LAPTOP}:\n"
    assert anchor in text
    return text.replace(anchor, anchor + ros_graph.indented(laptop_vars(prefix), 6), 1)


def screenshot(lab) -> xwd.Screenshot:
    lab.ok(LAPTOP, f"{X} xwd -root -silent > {SHOT}")
    stream, _ = client().containers.get(f"{lab.prefix}-{LAPTOP}").get_archive(SHOT)
    with tarfile.open(fileobj=io.BytesIO(b"".join(stream))) as tar:
        return xwd.read(tar.extractfile(tar.getmembers()[0]).read())


def rviz_window(lab) -> tuple[int, int, int, int] | None:
    """x, y, width, height of rviz's top-level window, None while there is none."""
    tree = lab.ok(LAPTOP, f"{X} xwininfo -root -children")
    line = next((line for line in tree.splitlines() if "RViz" in line and "x" in line.split('"')[-1]), None)
    if line is None:
        return None
    geometry = line.split('"')[-1].split()[-2]  # "1200x800+0+0"
    size, _, rest = geometry.partition("+")
    x, _, y = rest.partition("+")
    width, _, height = size.partition("x")
    return int(x), int(y), int(width), int(height)


def drawn(shot: xwd.Screenshot) -> bool:
    """rviz's window has drawn: its widgets and their text (many colours), the 3D view's
    background over a tenth of it and the grid's lines on it."""
    colours = shot.colours()
    return len(colours) >= 32 and colours[BACKGROUND] >= shot.width * shot.height // 10 and colours[GRID] >= 1000


@pytest.fixture(scope="module")
def rviz(lab, first_run, tmp_path_factory):
    started = time.monotonic()
    ros_images.ensure(lab.state)
    image = ros_images.ensure(lab.state, ros_images.RVIZ)
    phase("rviz: ros-core and rviz images in the lab registry", started)

    started = time.monotonic()
    lab.ok(
        LAPTOP,
        "DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends xvfb xinit x11-utils "
        "x11-xserver-utils x11-apps",
    )
    lab.ok(
        LAPTOP,
        "printf '#!/bin/sh\\nexec sleep infinity\\n' > /usr/local/bin/lab-session && chmod 755 "
        "/usr/local/bin/lab-session",
    )
    login(lab, LAPTOP)
    phase("rviz: X login on the laptop", started)

    fleet = tmp_path_factory.mktemp("rviz") / "lab.yaml"
    fleet.write_text(fleet_text(lab.prefix))
    run = lab.provision(
        "--limit", ROBOT, "--limit", LAPTOP, fleet=fleet, label="(robot2: the ROS graph, laptop1: rviz)"
    )
    assert run.returncode == 0, run.output[-6000:]
    # Nothing drew on the display yet: the checks below cannot pass on a bare X server.
    assert rviz_window(lab) is None and not drawn(screenshot(lab))

    started = time.monotonic()
    # As root (sudo on a laptop): the release directory is root's alone (0700), the docker group cannot read it.
    lab.ok(LAPTOP, f"docker compose -f {COMPOSE} up -d")
    yield image
    lab.sh(LAPTOP, f"docker compose -f {COMPOSE} down")
    lab.sh(LAPTOP, "pkill -u alice -f xinit; pkill -u alice Xvfb; true")
    phase("rviz: up to the checks' end", started)


def test_rviz_draws_on_the_laptops_display(lab, rviz):
    wait_for(lambda: rviz_window(lab) is not None, 120, "rviz's window on the laptop's display")
    window = rviz_window(lab)
    shots = []

    def looked() -> bool:  # rviz maps its window before its first frame: the view fills in a little later
        shots.append(screenshot(lab))
        return drawn(shots[-1].crop(*window))

    wait_for(looked, 90, "rviz's window drawn")
    target = os.environ.get(SCREENSHOT_ENV)
    path = ROOT / target if target else ROOT / ".lab" / lab.prefix / "rviz.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(xwd.png(shots[-1]))
    print(f"rviz screenshot: {path}")
    colours = shots[-1].crop(*window).colours()
    assert len(colours) >= 32 and colours[BACKGROUND] and colours[GRID], colours.most_common(5)


def rviz_nodes(lab) -> list[str]:
    return [node for node in lab.ok(ROBOT, f"docker exec {ROSCORE} rosnode list").split() if node.startswith("/rviz")]


def test_rviz_is_a_node_of_the_robots_graph(lab, rviz):
    """rviz joined robot2's graph (its master, beside the guide's nodes), and robot2 reaches it back by
    the laptop's ROS_HOSTNAME."""
    wait_for(lambda: rviz_nodes(lab), 60, "an rviz node in robot2's graph")
    node = rviz_nodes(lab)[0]
    assert {"/talker", "/listener", "/rosout", node} <= set(
        lab.ok(ROBOT, f"docker exec {ROSCORE} rosnode list").split()
    )
    assert f"http://{lab.prefix}-{LAPTOP}:" in lab.ok(ROBOT, f"docker exec {ROSCORE} rosnode info {node}")
    assert "reply from" in lab.ok(ROBOT, f"docker exec {ROSCORE} rosnode ping -c 1 {node}")


def test_rviz_runs_with_the_cookie_and_the_payloads_ros_settings(lab, rviz):
    container = lab.payload(LAPTOP)
    repository = rviz.rpartition(":")[0]
    assert container["Config"]["Image"].startswith(f"{repository}@sha256:")  # the release pins the digest
    env = dict(item.split("=", 1) for item in container["Config"]["Env"])
    assert env["DISPLAY"] == ":0" and env["XAUTHORITY"] == "/tmp/.robot-x11/Xauthority"
    assert env["ROS_MASTER_URI"] == f"http://{lab.prefix}-{ROBOT}:11311"
    assert env["ROS_HOSTNAME"] == f"{lab.prefix}-{LAPTOP}"
    mounts = {m["Destination"]: (m["Source"], m["RW"]) for m in container["Mounts"]}
    assert mounts["/tmp/.robot-x11"] == ("/var/lib/robot-x11/alice", False)
    # The display stays closed to everyone else.
    assert "access control enabled" in lab.ok(LAPTOP, "su - alice -c 'DISPLAY=:0 xhost'")
