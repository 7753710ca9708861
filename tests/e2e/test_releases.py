"""End to end: health-gated releases, automatic and manual rollback, the
update lock, push delivery and the fleet status, on the simulated fleet.
Runs after test_fleet.py (robot2 is then on 1.1, the others on 1.0)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.e2e.conftest import ROOT

pytestmark = pytest.mark.e2e

ALL_TAG = 'payload_image: "@registry@/ros/payload:1.0"'


def status(lab) -> dict[str, dict]:
    proc = subprocess.run(
        [sys.executable, "-m", "robotfleet", "status", "inventories/lab.py", "--json"],
        cwd=ROOT,
        env=dict(os.environ, ROBOT_LAB_PREFIX=lab.prefix),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    return {row["host"]: row for row in json.loads(proc.stdout)}


@pytest.fixture(scope="module")
def fleet_on(lab, first_run, tmp_path_factory):
    """fleet_on(tag, **host_lines): a fleet file with every host on `tag`."""

    def make(tag: str, extra: dict[str, str] | None = None):
        path = tmp_path_factory.mktemp("fleet")
        replacements = {ALL_TAG: f'payload_image: "@registry@/ros/payload:{tag}"', **(extra or {})}
        return lab.fleet_with(path, **replacements)

    return make


def test_update_to_a_good_tag(lab, fleet_on):
    behind = {h for h in lab.robots if lab.version(h) != "1.1"}
    run = lab.provision(fleet=fleet_on("1.1"), label="(fleet to 1.1)")
    assert run.returncode == 0, run.output[-4000:]
    assert run.changed_hosts == behind | set(lab.laptops)  # robot2 is already on 1.1 after test_fleet
    rows = status(lab)
    for host in lab.robots:
        assert lab.version(host) == "1.1"
        assert lab.payload(host)["State"]["Health"]["Status"] == "healthy"
        current = lab.record(host)
        assert current["state"] == "active"
        assert rows[host]["release"] == current["id"] and rows[host]["health"] == "healthy"
        pinned = current["images"][f"{lab.state['registry']}/ros/payload:1.1"]["pinned"]  # repository@digest
        assert rows[host]["image"] == f"{lab.state['registry']}/ros/payload:1.1@{pinned.split('@')[1]}"  # the tag kept
        assert rows[host]["previous"] == lab.record(host, "previous")["id"]
    assert rows["laptop1"]["release_state"] == "staged"


def test_update_to_a_broken_tag_rolls_every_robot_back(lab, fleet_on):
    before = {h: lab.record(h)["id"] for h in lab.robots}
    run = lab.provision(fleet=fleet_on("1.2-broken"), label="(fleet to 1.2-broken)")
    assert run.returncode != 0
    assert run.failed_hosts == set(lab.robots)
    for host in lab.robots:
        line = next(line for line in run.output.splitlines() if f"[{host}]" in line and "payload: release" in line)
        assert "unhealthy" in line and f"rolled back to {before[host]} and it is running" in line
        assert lab.record(host)["id"] == before[host]
        assert lab.version(host) == "1.1"
        assert lab.payload(host)["State"]["Health"]["Status"] == "healthy"
        failed = [
            json.loads(lab.ok(host, f"cat {p}"))
            for p in lab.ok(host, "ls -d /var/lib/robot-payload/releases/*/record.json").split()
        ]
        assert any(r["state"] == "failed" and "unhealthy" in r["reason"] for r in failed)
        assert "unhealthy" in status(lab)[host]["rolled_back_from"]["reason"]
    rows = status(lab)
    assert all(rows[h]["release"] == before[h] and rows[h]["health"] == "healthy" for h in lab.robots)


def test_manual_rollback_of_one_robot_changes_it_alone(lab):
    before = {h: lab.payload(h)["Id"] for h in lab.robots}
    previous = lab.record("robot1", "previous")["id"]
    run = lab.provision("--limit", "robot1", script="rollback.py", label="(rollback robot1)")
    assert run.returncode == 0, run.output[-3000:]
    assert lab.record("robot1")["id"] == previous
    assert lab.version("robot1") == "1.0"
    for host in set(lab.robots) - {"robot1"}:
        assert lab.payload(host)["Id"] == before[host]
    rows = status(lab)
    assert rows["robot1"]["release"] == previous and rows["robot1"]["health"] == "healthy"
    assert rows["robot2"]["release"] != previous


def test_update_lock_refuses_unless_forced(lab, fleet_on):
    lab.ok("robot3", "mkdir -p /run/robot-payload && echo 'robot is moving' > /run/robot-payload/update.lock")
    try:
        fleet = fleet_on("1.0")
        run = lab.provision("--limit", "robot3", fleet=fleet, label="(robot3 to 1.0, locked)")
        assert run.returncode != 0
        assert "update refused, /run/robot-payload/update.lock is held (robot is moving)" in run.output
        assert lab.version("robot3") == "1.1"
        assert status(lab)["robot3"]["lock"] == "robot is moving"
        forced = lab.provision("--limit", "robot3", "--data", "payload_force=true", fleet=fleet, label="(forced)")
        assert forced.returncode == 0, forced.output[-3000:]
        assert lab.version("robot3") == "1.0"
    finally:
        lab.ok("robot3", "rm -f /run/robot-payload/update.lock")


def test_push_delivery_to_a_robot_without_registry(lab, fleet_on):
    import docker

    engine = docker.from_env()
    engine.images.get("ros/payload:1.1").tag("offline.invalid/ros/payload", "1.1")
    extra = {
        "      udev_sensors:\n        - {name: gps,": (
            "      payload_delivery: push\n      payload_image: offline.invalid/ros/payload:1.1\n"
            "      udev_sensors:\n        - {name: gps,"
        ),
    }
    fleet = fleet_on("1.0", extra)
    assert lab.sh("robot3", "docker pull offline.invalid/ros/payload:1.1")[0] != 0  # no route to that registry
    # Another local user plants a file where the image used to be uploaded: nothing is written to a path.
    image_id = engine.images.get("offline.invalid/ros/payload:1.1").id.split(":")[-1]
    planted = f"/tmp/robotprov-image-{image_id[:16]}.tar"
    lab.ok("robot3", f"echo planted > {planted} && chown ros {planted} && chmod 644 {planted}")
    run = lab.provision("--limit", "robot3", fleet=fleet, label="(robot3 by push)")
    assert run.returncode == 0, run.output[-3000:]
    assert lab.ok("robot3", f"cat {planted}") == "planted\n"
    assert lab.ok("robot3", "ls /tmp").split().count(planted.rsplit("/", 1)[1]) == 1
    assert lab.version("robot3") == "1.1"
    sent = lab.ok("robot3", "cat /var/lib/robot-payload/push.log").splitlines()
    assert len(sent) == 1
    again = lab.provision("--limit", "robot3", fleet=fleet, label="(robot3 by push, again)")
    assert again.changed_hosts == set()
    assert lab.ok("robot3", "cat /var/lib/robot-payload/push.log").splitlines() == sent
    assert status(lab)["robot3"]["image"] == "offline.invalid/ros/payload:1.1"


ROBOT1 = "    robot1:\n      udev_sensors:"
LOOP = "while :; do touch /tmp/heartbeat; sleep 1 & wait $!; done"


def old_payload_stop(lab, host: str, since: str) -> float:
    """Docker's first signal to the old payload container (kill) -> its exit (die), read on the robot."""
    out = lab.ok(
        host,
        f"docker events --since {since} --until $(date +%s.%N) --filter type=container "
        "--filter event=kill --filter event=die --format '{{json .}}'",
    )
    events = [json.loads(line) for line in out.splitlines() if line.strip()]
    die = next(e for e in events if e["Action"] == "die")
    kill = next(e for e in events if e["Action"] == "kill" and e["id"] == die["id"])
    return (die["timeNano"] - kill["timeNano"]) / 1e9


@pytest.mark.parametrize(
    "what, lines, inspect",
    [
        # A ROS launch shuts down on SIGINT only; as PID 1 it would sit out Docker's SIGTERM for 10 s.
        (
            "a SIGINT-only payload under ros_preset",
            f"      ros_preset: ros2\n      payload_command: [/bin/sh, -c, \"trap 'exit 0' INT; {LOOP}\"]\n",
            lambda c: c["Config"]["StopSignal"] == "SIGINT",
        ),
        # A shell entrypoint without a trap ignores every signal as PID 1; under an init it does not.
        (
            "a shell with no trap under payload_init",
            f"      payload_init: true\n      payload_stop_grace_period: 5\n"
            f'      payload_command: [/bin/sh, -c, "{LOOP}"]\n',
            lambda c: c["HostConfig"]["Init"] is True,
        ),
    ],
)
def test_an_update_stops_the_old_payload_by_its_own_signal(lab, fleet_on, what, lines, inspect):
    """issue 29 item 5: the old release's stop inside an update is under a
    second, not Docker's 10 s default and a kill."""
    try:
        setup = lab.provision(
            "--limit",
            "robot1",
            fleet=fleet_on("1.0", {ROBOT1: f"    robot1:\n{lines}      udev_sensors:"}),
            label=f"(robot1: {what})",
        )
        assert setup.returncode == 0, setup.output[-3000:]
        assert inspect(lab.payload("robot1")), lab.payload("robot1")["Config"]
        since = lab.ok("robot1", "date +%s.%N").strip()
        run = lab.provision(
            "--limit",
            "robot1",
            fleet=fleet_on("1.1", {ROBOT1: f"    robot1:\n{lines}      udev_sensors:"}),
            label=f"(robot1 to 1.1: {what})",
        )
        assert run.returncode == 0, run.output[-3000:]
        assert lab.version("robot1") == "1.1" and inspect(lab.payload("robot1"))
        stop = old_payload_stop(lab, "robot1", since)
        assert stop < 2, f"{what}: the old payload took {stop:.2f} s to stop"
    finally:
        lab.provision("--limit", "robot1", fleet=fleet_on("1.0"), label="(robot1 back to the lab's settings)")
