"""End to end: a power cut during an update, then the same deploy as soon as
SSH answers (issue 21).  At every moment of the update the robot must run a
payload by itself within seconds of boot, and that first rerun must finish
the update with exit 0.

robot3 goes through the moments in turn, each update going the other way
between 1.0 and 1.1, and ends on the lab fleet's 1.0.  Each cut is a
`docker kill` + `docker start` of the host container (a real boot of its
systemd and Docker).  About 4-6 min: the boots dominate.

The last case makes the boot's own compose up slow (a `docker` wrapper put
on the payload unit's PATH by a drop-in sleeps 8 s before `compose up`), so
the deploy surely arrives while the recovery is in the middle of it; the
ordering itself (the boot holds the apply lock to the end of its compose up)
is also proven in the unit layer against stand-ins.
"""

from __future__ import annotations

import socket
import subprocess
import time

import pytest

from tests.e2e.conftest import wait_for
from tests.e2e.faults import (
    DIR,
    HEALTH_WAIT,
    NEW_CONTAINERS,
    Background,
    build_image_with_a_new_layer,
    image,
)

pytestmark = pytest.mark.e2e

HOST = "robot3"
SLOW_DOCKER = """#!/bin/sh
case " $* " in *" compose "*" up "*) touch /run/slow-compose-up; sleep 8 ;; esac
exec /usr/bin/docker "$@"
"""
SLOW_UNIT = "/etc/systemd/system/robot-payload.service.d/slow-compose-up.conf"


def on(lab, version: str) -> bool:
    try:
        return lab.version(HOST) == version and lab.record(HOST)["state"] == "active"
    except AssertionError:
        return False


def payload_running(lab) -> bool:
    code, out = lab.sh(
        HOST, "docker ps -q --filter label=com.docker.compose.project=robot-payload --filter status=running"
    )
    return code == 0 and bool(out.strip())


def ssh_answers(lab) -> bool:
    port = next(h["port"] for h in lab.state["hosts"] if h["name"] == HOST)
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1) as conn:
            conn.settimeout(1)
            return conn.recv(64).startswith(b"SSH-")
    except OSError:
        return False


def cut_and_rerun(lab, deploy: Background, when: str, fleet, expect_waiting: bool = False):
    """Pull the plug when `when` holds on the robot, switch it on again, and
    start the same deploy the moment SSH answers.  Returns the rerun's output
    and the seconds from power-on to a running payload."""
    try:
        lab.ok(HOST, f"for i in $(seq 2400); do {when} && exit 0; sleep 0.025; done; exit 1")
    finally:
        container = f"{lab.prefix}-{HOST}"
        subprocess.run(["docker", "kill", container], check=True, capture_output=True)
        deploy.kill()
    subprocess.run(["docker", "start", container], check=True, capture_output=True)
    powered_on = time.monotonic()
    wait_for(lambda: ssh_answers(lab), 120, f"sshd on {HOST} after boot", interval=0.1)
    if expect_waiting:
        wait_for(
            lambda: lab.sh(HOST, "test -e /run/slow-compose-up")[0] == 0, 60, "the boot's compose up", interval=0.1
        )
    rerun = Background(lab, "--limit", HOST, fleet=fleet)
    wait_for(lambda: payload_running(lab), 90, f"a payload running on {HOST} after boot", interval=0.2)
    seconds = time.monotonic() - powered_on
    code, output = rerun.wait(600)
    assert code == 0, output[-4000:]
    return output, seconds


def test_a_rerun_right_after_boot_finishes_an_update_cut_at_any_moment(lab, first_run, tmp_path):
    to = {}
    for version in ("1.0", "1.1", "big"):
        path = tmp_path / version
        path.mkdir()
        # 64 MB the robot has never seen: its pull lasts long enough to be cut.
        tag = build_image_with_a_new_layer(lab, 64 << 20, "1.1-big64") if version == "big" else version
        to[version] = lab.fleet_with(path, **image(tag))
    run = lab.provision("--limit", HOST, fleet=to["1.0"], label=f"({HOST} on 1.0)")
    assert run.returncode == 0 and on(lab, "1.0"), run.output[-3000:]

    record = f"{DIR}/current/record.json"
    moments = [
        # (moment, the cut's condition on the robot, the update's target, its version label)
        ("as compose replaces the containers", NEW_CONTAINERS.format(version="1.1"), "1.1", "1.1"),
        ("during the pull", "pgrep -f 'docker [p]ull' >/dev/null", "big", "1.1"),
        ("right after the switch", f'grep -q \'"state": "switching"\' {record} 2>/dev/null', "1.0", "1.0"),
        ("during the health wait", HEALTH_WAIT, "1.1", "1.1"),
        (
            "right after verification",
            f'grep -q \'"state": "active"\' {record} && grep -q \'ros/payload:1.0"\' {record}',
            "1.0",
            "1.0",
        ),
    ]
    seconds = {}
    for moment, when, target, version in moments:
        deploy = Background(lab, "--limit", HOST, fleet=to[target])
        output, seconds[moment] = cut_and_rerun(lab, deploy, when, to[target])
        assert on(lab, version), f"{moment}: not on {version} after the rerun:\n{output[-3000:]}"
        assert "Conflict" not in output, output[-3000:]
    print(f"\n[e2e] power on -> a payload running: {seconds}")
    assert max(seconds.values()) < 60, seconds  # a boot of the container and its Docker, then compose up

    # The deploy arrives while the boot's recovery is in its compose up.
    lab.ok(
        HOST,
        "mkdir -p /usr/local/lab-slow /etc/systemd/system/robot-payload.service.d"
        f" && printf '%s' '{SLOW_DOCKER}' > /usr/local/lab-slow/docker && chmod 755 /usr/local/lab-slow/docker"
        " && printf '[Service]\\nEnvironment=PATH=/usr/local/lab-slow:/usr/sbin:/usr/bin:/sbin:/bin\\n' > "
        f"{SLOW_UNIT}"
        " && systemctl daemon-reload",
    )
    try:
        deploy = Background(lab, "--limit", HOST, fleet=to["1.1"])
        output, _ = cut_and_rerun(lab, deploy, HEALTH_WAIT, to["1.1"], expect_waiting=True)
        assert f"[{HOST}] {HOST} is recovering from an interrupted release since" in output, output[-3000:]
        assert on(lab, "1.1") and "Conflict" not in output
    finally:
        lab.ok(HOST, f"rm -rf {SLOW_UNIT} /usr/local/lab-slow /run/slow-compose-up && systemctl daemon-reload")
    run = lab.provision("--limit", HOST, label=f"({HOST} back on the lab fleet)")
    assert run.returncode == 0 and on(lab, "1.0"), run.output[-3000:]
    again = lab.provision("--limit", HOST, label=f"({HOST} converged)")
    assert again.returncode == 0 and again.changed_hosts == set(), again.output[-3000:]
