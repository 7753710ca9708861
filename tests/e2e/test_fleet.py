"""End to end: provision the simulated fleet over SSH and check every host
from inside.  The tests build on each other (one lab per session)."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
import time

import pytest

from tests.e2e.conftest import ROOT, phase
from tests.fixtures import pyinfra

pytestmark = pytest.mark.e2e

# What inventories/lab.yaml declares per robot, handed to the payload.
SENSOR_DEVICES = {
    "robot1": {"/dev/robot/front_camera", "/dev/robot/back_camera", "/dev/robot/lidar"},
    "robot2": {"/dev/robot/imu"},
    "robot3": {"/dev/robot/gps"},
}


def test_fresh_run_provisions_every_host(lab, first_run):
    assert first_run.failed_hosts == set()
    assert first_run.changed_hosts == set(lab.hosts)
    for host in lab.hosts:
        assert lab.ok(host, "systemctl is-active docker").strip() == "active"
        assert lab.ok(host, "systemctl is-enabled docker").strip() == "enabled"
        assert re.search(r"version v?2\.", lab.ok(host, "docker compose version"))
        daemon = json.loads(lab.ok(host, "cat /etc/docker/daemon.json"))
        assert daemon["live-restore"] is True and daemon["log-opts"]["max-size"] == "10m"
        assert daemon["insecure-registries"] == [lab.state["registry"]]
        # It may hold proxy credentials: root's alone (issue 27, item 7).
        assert lab.ok(host, "stat -c %a:%U:%G /etc/docker/daemon.json").strip() == "600:root:root"


def test_robots_run_docker_ce_from_the_mirror(lab, first_run):
    for host in lab.robots:
        status = lab.ok(host, "dpkg-query -W -f '${Status} ${Version}' docker-ce docker-compose-plugin")
        assert status.count("install ok installed") == 2 and "~debian.13~trixie" in status
        sources = lab.ok(host, "cat /etc/apt/sources.list.d/docker.sources")
        assert f"URIs: {lab.state['mirror_url']}/debian" in sources
        assert "Suites: trixie" in sources and "Architectures: amd64" in sources
        assert "Signed-By: /etc/apt/keyrings/docker.asc" in sources
        assert lab.ok(host, "stat -c %a /etc/apt/keyrings/docker.asc").strip() == "644"
        assert lab.sh(host, "dpkg-query -W -f '${Status}' docker.io | grep -q 'ok installed'")[0] != 0


def test_laptop_uses_the_distributions_engine(lab, first_run):
    for host in lab.laptops:
        assert "ok installed" in lab.ok(host, "dpkg-query -W -f '${Status}' docker.io")
        assert lab.sh(host, "dpkg-query -W -f '${Status}' docker-ce 2>/dev/null | grep -q 'ok installed'")[0] != 0
        assert lab.sh(host, "test -e /etc/apt/sources.list.d/docker.sources")[0] != 0


def test_users_are_in_the_docker_group(lab, first_run):
    for host in lab.robots:
        for user in ("ops", "ros"):
            assert "docker" in lab.ok(host, f"id -nG {user}").split()
    for host in lab.laptops:
        assert "docker" in lab.ok(host, "id -nG alice").split()
        assert "docker" not in lab.ok(host, "id -nG ros").split()


def test_udev_rules_are_in_place_and_accepted(lab, first_run):
    for host in lab.robots:
        rules = lab.ok(host, "cat /etc/udev/rules.d/70-robot-sensors.rules")
        assert 'SYMLINK+="robot/' in rules
        lab.ok(
            host,
            "udevadm verify --resolve-names=never /etc/udev/rules.d/70-robot-sensors.rules "
            "/etc/udev/rules.d/60-usb-serial-low-latency.rules",
        )
    front, back = (
        line
        for line in lab.ok("robot1", "cat /etc/udev/rules.d/70-robot-sensors.rules").splitlines()
        if "camera" in line and not line.startswith("#")
    )
    assert 'KERNELS=="1-1.2"' in front and 'KERNELS=="1-1.3"' in back


def test_payload_unit_runs_the_declared_image_healthy(lab, first_run):
    for host in lab.robots:
        assert lab.ok(host, "systemctl is-enabled robot-payload").strip() == "enabled"
        assert lab.ok(host, "systemctl is-active robot-payload").strip() == "active"
        container = lab.payload(host)
        assert container["State"]["Health"]["Status"] == "healthy"
        assert container["Config"]["Image"].startswith(f"{lab.state['registry']}/ros/payload@sha256:")
        assert container["Config"]["Labels"]["org.opencontainers.image.version"] == "1.0"
        assert "ROS_DOMAIN_ID=7" in container["Config"]["Env"]
        devices = {d["PathOnHost"] for d in container["HostConfig"]["Devices"]}
        assert devices == SENSOR_DEVICES[host]
        record = json.loads(lab.ok(host, "cat /var/lib/robot-payload/current/record.json"))
        assert record["state"] == "active"
    for host in lab.laptops:
        assert lab.sh(host, "systemctl cat robot-payload")[0] != 0  # no autostart on laptops
        record = json.loads(lab.ok(host, "cat /var/lib/robot-payload/current/record.json"))
        assert record["state"] == "staged"
        lab.ok(host, "docker image inspect " + lab.state["registry"] + "/ros/payload:1.0")


def test_second_run_changes_nothing(lab, first_run):
    run = lab.provision(label="(second run)")
    assert run.returncode == 0, run.output[-4000:]
    assert {h: run.changes(h) for h in lab.hosts} == {h: [] for h in lab.hosts}


def test_dry_diff_shows_a_drifted_daemon_json_and_changes_nothing(lab, first_run):
    """`--dry --diff` (no -y: planning is what it shows) on a robot whose
    daemon.json drifted prints the diff, and leaves the file and Docker alone."""
    host = "robot3"
    original = lab.ok(host, "cat /etc/docker/daemon.json")
    drifted = original.replace('"max-size": "10m"', '"max-size": "1m"')
    assert drifted != original
    started = lab.ok(host, "systemctl show -p ActiveEnterTimestampMonotonic docker.service")
    lab.ok(host, f"printf %s {shlex.quote(drifted)} > /etc/docker/daemon.json")
    try:
        env = dict(os.environ, ROBOT_LAB_PREFIX=lab.prefix, PYINFRA_PROGRESS="off")
        proc = pyinfra("--dry", "--diff", "--limit", host, "inventories/lab.py", "deploy.py", env=env, timeout=300)
        output = proc.stdout + proc.stderr
        assert proc.returncode == 0, output[-4000:]
        assert "Will modify /etc/docker/daemon.json" in output
        assert '-    "max-size": "1m"' in output and '+    "max-size": "10m"' in output, output[-4000:]
        # robotfleet deploy runs the same deploy: the same operations, the same lines (issue 54, item 2)
        began = time.monotonic()
        ours = subprocess.run(
            [sys.executable, "-m", "robotfleet", "deploy", "-i", "inventories/lab.py", "--dry", "--diff"]
            + ["--limit", host],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        phase("robotfleet deploy --dry --diff (one robot)", began)
        assert ours.returncode == 0, (ours.stdout + ours.stderr)[-4000:]
        assert (ours.stdout, ours.stderr.splitlines()) == (proc.stdout, proc.stderr.splitlines())
        assert lab.ok(host, "cat /etc/docker/daemon.json") == drifted
        assert lab.ok(host, "systemctl show -p ActiveEnterTimestampMonotonic docker.service") == started
    finally:
        lab.ok(host, f"printf %s {shlex.quote(original)} > /etc/docker/daemon.json")


def test_changing_one_robots_tag_changes_that_robot_alone(lab, first_run, tmp_path):
    before = {h: lab.payload(h)["Id"] for h in lab.robots}
    fleet = lab.fleet_with(
        tmp_path,
        **{
            "      udev_sensors:\n        - {name: imu,": '      payload_image: "@registry@/ros/payload:1.1"\n      '
            "udev_sensors:\n        - {name: imu,"
        },
    )
    run = lab.provision(fleet=fleet, label="(robot2 to 1.1)")
    assert run.returncode == 0, run.output[-4000:]
    assert run.changed_hosts == {"robot2"}
    assert run.changes("robot2") == ["Payload | Release the payload (pull, switch, health check, roll back on failure)"]
    container = lab.payload("robot2")
    assert container["Config"]["Labels"]["org.opencontainers.image.version"] == "1.1"
    assert container["State"]["Health"]["Status"] == "healthy"
    for host in set(lab.robots) - {"robot2"}:
        assert lab.payload(host)["Id"] == before[host]  # untouched, not restarted
    again = lab.provision(fleet=fleet, label="(robot2 at 1.1, rerun)")
    assert again.changed_hosts == set()
