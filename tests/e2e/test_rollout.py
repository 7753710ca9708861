"""End to end: rollouts in waves on the simulated fleet (3 robots).

A good image goes through every wave (an unreachable robot is skipped, and
rerunning the same command finishes it); a bad image stops after the canary
with the other robots untouched; a budget of one failure lets one through
and stops at the second."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.e2e.conftest import ROOT, phase

pytestmark = pytest.mark.e2e

ALL_TAG = 'payload_image: "@registry@/ros/payload:1.0"'
# Short health windows keep this module fast; the tags are all that differ.
FAST = {
    "payload_health_timeout: 60": "payload_health_timeout: 20",
    "payload_stable_seconds: 5": "payload_stable_seconds: 2",
}


@pytest.fixture(scope="module")
def rollout(lab, first_run, tmp_path_factory):
    states = tmp_path_factory.mktemp("rollout-state")

    def fleet(tag: str):
        return lab.fleet_with(
            tmp_path_factory.mktemp("fleet"), **FAST, **{ALL_TAG: f'payload_image: "@registry@/ros/payload:{tag}"'}
        )

    def run(tag, *args: str):
        """A rollout to ``tag`` of the lab fleet, or of the fleet file ``tag`` names (a Path)."""
        import time

        env = dict(
            os.environ,
            ROBOT_LAB_PREFIX=lab.prefix,
            ROBOT_LAB_FLEET=str(tag if isinstance(tag, Path) else fleet(tag)),
            ROBOT_ROLLOUT_DIR=str(states),
            PYINFRA_PROGRESS="off",
        )
        started = time.monotonic()
        proc = subprocess.run(
            [sys.executable, "-m", "robotfleet", "rollout", "inventories/lab.py", "--limit", "robots", "-y", *args],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
        )
        phase(f"rollout to {tag} {' '.join(args)} (exit {proc.returncode})", started)
        return proc.returncode, proc.stdout + proc.stderr

    def status():
        proc = subprocess.run(
            [sys.executable, "-m", "robotfleet", "status", "inventories/lab.py", "--limit", "robots", "--json"],
            cwd=ROOT,
            env=dict(os.environ, ROBOT_LAB_PREFIX=lab.prefix, ROBOT_ROLLOUT_DIR=str(states)),
            capture_output=True,
            text=True,
            timeout=120,
        )
        return {row["host"]: row for row in json.loads(proc.stdout)}

    run.status = status
    run.fleet = fleet
    return run


def releases(lab, host):
    return lab.ok(host, "ls /var/lib/robot-payload/releases").split()


def waves_run(output):
    return [line.split(": ", 1)[1] for line in output.splitlines() if line.startswith("--> wave ")]


def test_a_good_image_goes_through_every_wave_and_a_rerun_finishes_a_skipped_robot(lab, rollout):
    setup = lab.provision("--limit", "robots", fleet=rollout.fleet("1.0"), label="(robots on 1.0)")
    assert setup.returncode == 0, setup.output[-3000:]
    lab.ok("robot3", "systemctl stop ssh.socket ssh.service 2>/dev/null; systemctl stop ssh")
    try:
        code, output = rollout("1.1", "--canary", "1", "--batch", "1")
        assert code == 3, output[-3000:]  # incomplete only because robot3 was unreachable
        assert waves_run(output) == ["robot1", "robot2", "robot3"]
        assert "rollout: [robot3] skipped: unreachable" in output
        assert [lab.version(h) for h in ("robot1", "robot2", "robot3")] == ["1.1", "1.1", "1.0"]
    finally:
        lab.ok("robot3", "systemctl start ssh")
    code, output = rollout("1.1", "--canary", "1", "--batch", "1")
    assert code == 0, output[-3000:]
    assert waves_run(output) == ["robot3"]  # the others are already on 1.1
    for host in lab.robots:
        assert lab.version(host) == "1.1"
        assert lab.payload(host)["State"]["Health"]["Status"] == "healthy"
    assert {row["rollout"] for row in rollout.status().values()} == {"wave 1/3 done", "wave 2/3 done", "wave 3/3 done"}


def test_a_bad_image_stops_after_the_canary_and_leaves_the_others_untouched(lab, rollout):
    before = {h: (lab.payload(h)["Id"], releases(lab, h)) for h in lab.robots}
    code, output = rollout("1.2-broken", "--canary", "1", "--batch", "1", "--max-failed", "0")
    assert code == 1
    assert waves_run(output) == ["robot1"]
    assert "rollout: [robot1] failed: " in output and "unhealthy" in output
    assert "resume:   robotfleet rollout inventories/lab.py --limit robots -y --canary 1" in output
    assert lab.version("robot1") == "1.1" and lab.record("robot1")["rolled_back_from"]
    for host in ("robot2", "robot3"):
        assert (lab.payload(host)["Id"], releases(lab, host)) == before[host]
    rows = rollout.status()
    assert [rows[h]["rollout"] for h in lab.robots] == ["wave 1/3 failed", "wave 2/3 pending", "wave 3/3 pending"]


def test_a_budget_of_one_lets_one_failure_through_and_stops_at_the_second(lab, rollout):
    before = (lab.payload("robot3")["Id"], releases(lab, "robot3"))
    code, output = rollout("1.2-broken", "--canary", "1", "--batch", "1", "--max-failed", "1")
    assert code == 1
    assert waves_run(output) == ["robot1", "robot2"]
    for host in ("robot1", "robot2"):
        assert f"rollout: [{host}] failed: " in output
        assert lab.version(host) == "1.1" and lab.payload(host)["State"]["Health"]["Status"] == "healthy"
    assert (lab.payload("robot3")["Id"], releases(lab, "robot3")) == before


def test_a_rollout_of_robots_with_several_services_completes(lab, rollout, tmp_path_factory):
    """The rollout's target is every image of a robot's compose project (issue
    16): robots that use payload_services were counted as failed (the target
    was payload_image alone), so such a rollout stopped at its canary."""
    from tests.e2e.twoservices import SECRET_FILE, two_services

    def fleet(driver: str) -> Path:
        return lab.fleet_with(
            tmp_path_factory.mktemp("services"),
            **FAST,
            **{f"    {ALL_TAG}\n": two_services(payload="1.1", driver=driver)},
        )

    setup = lab.provision("--limit", "robots", fleet=fleet("1.0"), label="(robots with two services)")
    assert setup.returncode == 0, setup.output[-3000:]
    try:
        code, output = rollout(fleet("1.1"), "--canary", "1", "--batch", "2")
        assert code == 0, output[-3000:]
        assert waves_run(output) == ["robot1", "robot2, robot3"]
        for host, row in rollout.status().items():
            assert row["image_refs"] == sorted(
                [f"{lab.state['registry']}/ros/driver:1.1", f"{lab.state['registry']}/ros/payload:1.1"]
            ), (host, row)
            assert row["state"] == "driver:running, payload:running"
    finally:
        SECRET_FILE.unlink(missing_ok=True)
        back = lab.provision("--limit", "robots", fleet=rollout.fleet("1.1"), label="(robots back to one service)")
        assert back.returncode == 0, back.output[-3000:]
