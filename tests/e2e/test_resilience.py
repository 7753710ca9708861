"""End to end: a dropped SSH link during an update, and a reboot."""

from __future__ import annotations

import os
import signal
import subprocess

import pytest

from tests.e2e.conftest import wait_for
from tests.fixtures import start_pyinfra

pytestmark = pytest.mark.e2e


def test_dropped_link_during_an_update_leaves_the_robot_switched(lab, first_run, tmp_path):
    target = "1.1" if lab.version("robot1") != "1.1" else "1.0"
    fleet = lab.fleet_with(
        tmp_path, **{'payload_image: "@registry@/ros/payload:1.0"': f'payload_image: "@registry@/ros/payload:{target}"'}
    )
    # Hold the helper's own lock so the update waits on the robot, then cut
    # the operator off while it waits (as a dropped link would).
    lab.ok("robot1", "systemd-run --unit=hold-apply-lock flock /var/lib/robot-payload/lock/apply.lock sleep 8")
    env = dict(os.environ, ROBOT_LAB_PREFIX=lab.prefix, ROBOT_LAB_FLEET=str(fleet), PYINFRA_PROGRESS="off")
    operator = start_pyinfra(
        "-y",
        "inventories/lab.py",
        "deploy.py",
        "--limit",
        "robot1",
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        wait_for(
            lambda: (
                "robot-payload-update" in lab.ok("robot1", "systemctl list-units --no-legend 'robot-payload-update-*'")
            ),
            60,
            "the update to start on robot1",
        )
    finally:
        os.killpg(operator.pid, signal.SIGKILL)
        operator.wait()
    wait_for(
        lambda: (
            "robot-payload-update" not in lab.ok("robot1", "systemctl list-units --no-legend 'robot-payload-update-*'")
        ),
        90,
        "the update on robot1 to finish without the operator",
    )
    assert lab.version("robot1") == target
    assert lab.payload("robot1")["State"]["Health"]["Status"] == "healthy"
    assert lab.record("robot1")["state"] == "active"
    rerun = lab.provision("--limit", "robot1", fleet=fleet, label="(robot1 after the dropped link)")
    assert rerun.returncode == 0 and rerun.changed_hosts == set()


def test_payload_comes_back_after_a_reboot(lab, first_run, tmp_path):
    before = lab.record("robot2")["id"]
    running = lab.version("robot2")  # the fleet file that matches what robot2 runs now
    fleet = lab.fleet_with(
        tmp_path,
        **{'payload_image: "@registry@/ros/payload:1.0"': f'payload_image: "@registry@/ros/payload:{running}"'},
    )
    restarted_at = lab.ok("robot2", "date -u +%Y-%m-%dT%H:%M:%S").strip()
    subprocess.run(["docker", "restart", "-t", "30", f"{lab.prefix}-robot2"], check=True, capture_output=True)
    wait_for(
        lambda: lab.sh("robot2", "systemctl is-active robot-payload")[1].strip() == "active",
        120,
        "robot-payload.service to start at boot",
    )
    wait_for(
        lambda: lab.payload("robot2")["State"].get("Health", {}).get("Status") == "healthy",
        60,
        "the payload to be healthy after boot",
    )
    assert lab.record("robot2")["id"] == before
    # Shutdown ran `compose down`; the unit created the container again at boot.
    assert lab.payload("robot2")["Created"][:19] >= restarted_at
    run = lab.provision("--limit", "robot2", fleet=fleet, label="(robot2 after reboot)")
    assert run.returncode == 0 and run.changed_hosts == set()
