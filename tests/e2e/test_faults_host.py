"""End to end: faults of the host under the payload (issue 7, host half).

Docker restarted or reinstalled under a running payload, a daemon.json Docker
refuses to start with, udev triggers that fail, the apt/dpkg lock held by
another process, and a fresh provision cut off at several steps (dropped SSH
links, a power cut while dpkg installs Docker).  Each check leaves its robot
as first_run left it (robots on 1.0), for the modules that run after it.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest

from tests.e2e.conftest import wait_for
from tests.fixtures import start_pyinfra

pytestmark = pytest.mark.e2e

ALL_TAG = 'payload_image: "@registry@/ros/payload:1.0"'
REGISTRIES = '    docker_insecure_registries: ["@registry@"]\n'
HEALTH_WINDOW = 60  # payload_health_timeout in inventories/lab.yaml


def healthy(lab, host: str) -> bool:
    code, out = lab.sh(
        host, "docker ps -q --filter label=com.docker.compose.project=robot-payload --filter health=healthy"
    )
    return code == 0 and len(out.split()) == 1


def kept_running(lab, host: str, before: dict) -> None:
    """The payload container `before` is still the one running, never restarted, and healthy."""
    wait_for(lambda: healthy(lab, host), HEALTH_WINDOW, f"the payload on {host} to be healthy")
    after = lab.payload(host)
    assert (after["Id"], after["State"]["StartedAt"]) == (before["Id"], before["State"]["StartedAt"])
    assert lab.ok(host, "systemctl is-active robot-payload.service").strip() == "active"


def converged(lab, host: str, label: str, fleet=None) -> None:
    run = lab.provision("--limit", host, fleet=fleet, label=label)
    assert run.returncode == 0, run.output[-4000:]
    assert run.changed_hosts == set(), run.changes(host)


def lines_with(output: str, text: str) -> list[str]:
    return [line.strip() for line in output.splitlines() if text in line]


@pytest.fixture(scope="module")
def fleet(lab, first_run, tmp_path_factory):
    """fleet(**replacements): a copy of inventories/lab.yaml with text replaced."""
    return lambda **replacements: lab.fleet_with(tmp_path_factory.mktemp("fleet"), **replacements)


def test_docker_restart_and_engine_reinstall_keep_the_payload_running(lab, first_run):
    host = "robot2"
    before = lab.payload(host)
    lab.ok(host, "systemctl restart docker.service")
    kept_running(lab, host, before)

    containerd = lab.ok(host, "systemctl show -p MainPID --value containerd.service").strip()
    lab.ok(host, "DEBIAN_FRONTEND=noninteractive apt-get install -y -q --reinstall docker-ce containerd.io")
    # The package restarted the container runtime under the payload.
    assert lab.ok(host, "systemctl show -p MainPID --value containerd.service").strip() != containerd
    kept_running(lab, host, before)
    converged(lab, host, "(robot2 after Docker restarts)")


def test_daemon_json_docker_refuses_is_put_back_and_the_host_fails_with_the_reason(lab, fleet):
    host = "robot2"
    good = lab.ok(host, "sha256sum /etc/docker/daemon.json")
    before = lab.payload(host)
    # Valid JSON that `dockerd --validate` accepts, but Docker refuses to start
    # with: `hosts` conflicts with the unit's own `-H fd://`.
    refused = fleet(
        **{
            REGISTRIES: REGISTRIES
            + '    docker_daemon_options: {live-restore: true, hosts: ["unix:///var/run/docker.sock"]}\n'
        }
    )
    run = lab.provision("--limit", host, fleet=refused, label="(robot2, a daemon.json Docker refuses)")
    assert run.returncode != 0  # (the only host failed: pyinfra prints no results)
    reason = lines_with(run.output, "docker: Docker did not start with the new daemon.json")
    assert len(reason) == 1, run.output[-4000:]
    assert "specified both as a flag and in the configuration file: hosts" in reason[0]
    assert reason[0].endswith("the previous daemon.json is restored and Docker runs again")
    assert lab.ok(host, "sha256sum /etc/docker/daemon.json") == good
    assert lab.sh(host, "test -e /etc/docker/daemon.json.pending")[0] != 0
    assert lab.ok(host, "systemctl is-active docker.service").strip() == "active"
    kept_running(lab, host, before)
    converged(lab, host, "(robot2 after the refused daemon.json)")


def test_failed_udev_trigger_is_a_warning_and_the_payload_still_deploys(lab, fleet):
    host = "robot3"
    # udevd does run in this host; only its triggers fail (read-only /sys).
    lab.ok(host, "systemd-run --unit=lab-udevd /usr/lib/systemd/systemd-udevd")
    try:
        wait_for(lambda: lab.sh(host, "udevadm control --ping")[0] == 0, 20, "udevd in robot3")
        changed = fleet(
            **{
                '{name: gps, subsystem: tty, serial: "GPS-42"}': '{name: gps, subsystem: tty, serial: "GPS-42", '
                'mode: "0640"}',
                ALL_TAG: 'payload_image: "@registry@/ros/payload:1.1"',
            }
        )
        run = lab.provision("--limit", host, fleet=changed, label="(robot3, new rules, udev trigger fails)")
        assert run.returncode == 0, run.output[-4000:]
        warning = lines_with(run.output, "warning: udev: udevadm trigger failed for subsystem tty: ")
        assert len(warning) == 1, run.output[-4000:]
        assert "Failed to write 'change' to '/sys/devices/" in warning[0]  # names the device
        assert 'ATTRS{serial}=="GPS-42", SYMLINK+="robot/gps", GROUP="dialout", MODE="0640"' in lab.ok(
            host, "cat /etc/udev/rules.d/70-robot-sensors.rules"
        )
        assert lab.version(host) == "1.1" and healthy(lab, host)
        converged(lab, host, "(robot3 after the failed trigger)", fleet=changed)
    finally:
        lab.sh(host, "systemctl stop lab-udevd")
    back = lab.provision("--limit", host, label="(robot3 back to the lab fleet)")
    assert back.returncode == 0 and lab.version(host) == "1.0", back.output[-4000:]


HOLD_DPKG_LOCK = (
    "systemd-run --unit=hold-dpkg-lock python3 -c "
    '\'import fcntl, time; f = open("/var/lib/dpkg/lock-frontend", "w"); '
    "fcntl.lockf(f, fcntl.LOCK_EX); time.sleep(120)'"
)


LOCK_IS_FREE = (
    'python3 -c \'import fcntl; fcntl.lockf(open("/var/lib/dpkg/lock-frontend", "w"), fcntl.LOCK_EX | fcntl.LOCK_NB)\''
)


def test_held_apt_lock_fails_the_host_in_bound_naming_the_holder(lab, first_run):
    host = "robot1"
    lab.ok(host, "DEBIAN_FRONTEND=noninteractive apt-get remove -y -q docker-buildx-plugin")
    lab.ok(host, HOLD_DPKG_LOCK)  # as unattended-upgrades holds it at boot
    try:
        wait_for(lambda: lab.sh(host, LOCK_IS_FREE)[0] != 0, 10, "the lock holder")
        run = lab.provision("--limit", host, "--data", "apt_lock_timeout=5", label="(robot1, dpkg lock held)")
        assert run.returncode != 0
        line = lines_with(run.output, "apt: /var/lib/dpkg/lock-frontend is held by process ")
        assert len(line) == 1, run.output[-4000:]
        assert "python3 -c import fcntl" in line[0] and "for more than 5 s (apt_lock_timeout)" in line[0]
        assert run.seconds < 90
        # Nothing installed, nothing half-done.
        assert lab.sh(host, "dpkg-query -W -f '${Status}' docker-buildx-plugin | grep -q 'ok installed'")[0] != 0
        assert lab.ok(host, "dpkg --audit; ls -A /var/lib/dpkg/updates").strip() == ""
    finally:
        lab.sh(host, "systemctl stop hold-dpkg-lock")
    run = lab.provision("--limit", host, label="(robot1, lock released)")
    assert run.returncode == 0, run.output[-4000:]
    assert "ok installed" in lab.ok(host, "dpkg-query -W -f '${Status}' docker-buildx-plugin")
    converged(lab, host, "(robot1 after the lock)")


# --- a fresh robot cut off at several steps ----------------------------------


def start_deploy(lab, fleet_file, host: str) -> subprocess.Popen:
    env = dict(os.environ, ROBOT_LAB_PREFIX=lab.prefix, ROBOT_LAB_FLEET=str(fleet_file), PYINFRA_PROGRESS="off")
    return start_pyinfra(
        "-y",
        "inventories/lab.py",
        "deploy.py",
        "--limit",
        host,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def cut_when(lab, operator: subprocess.Popen, host: str, probe: str, what: str, power_cut: bool = False):
    """Poll `probe` in the host while the deploy runs; when it succeeds, kill
    the operator (a dropped link) or, with power_cut, the whole host first."""
    container = f"{lab.prefix}-{host}"
    deadline = time.monotonic() + 240
    try:
        while time.monotonic() < deadline:
            if lab.sh(host, probe)[0] == 0:
                if power_cut:
                    subprocess.run(["docker", "kill", container], check=True, capture_output=True)
                return
            assert operator.poll() is None, f"the deploy of {host} ended before {what}"
            time.sleep(0.1)
        raise AssertionError(f"{host}: {what} not reached in 240 s")
    finally:
        if operator.poll() is None:
            os.killpg(operator.pid, signal.SIGKILL)
        operator.wait()
        if power_cut:
            subprocess.run(["docker", "start", container], check=True, capture_output=True)
            wait_for(lambda: lab.sh(host, "systemctl is-active ssh.service")[0] == 0, 120, f"{host} to boot")


# dpkg marks a package half-installed (H), unpacked (U), half-configured (F)
# while it works on it; apt hands it the .debs in a directory, not by name.
DPKG_UNPACKS_DOCKER = (
    "dpkg-query -W -f='${db:Status-Abbrev}\\n' containerd.io docker-ce 2>/dev/null | grep -q '^.[HUF]'"
)
DAEMON_JSON_OR_RELEASE = (
    "test -e /etc/docker/daemon.json.pending || "
    "systemctl list-units --no-legend 'robot-payload-update-*' | grep -q update"
)


@pytest.fixture
def fresh_robot(lab, first_run, fleet):
    """robot4: a fresh host beside the lab, declared in its own fleet file; removed afterwards."""
    from tests.lab import hosts

    hosts.up(lab.prefix, robots=4, laptops=1)
    try:
        yield fleet(**{"\nlaptops:": "    robot4: {}\n\nlaptops:"})
    finally:
        hosts.up(lab.prefix, robots=3, laptops=1)


def test_fresh_provision_cut_off_at_each_step_finishes_on_rerun(lab, fresh_robot):
    host = "robot4"
    # 1. The link drops while apt runs (the prerequisites).
    cut_when(lab, start_deploy(lab, fresh_robot, host), host, "pgrep -x apt-get >/dev/null", "apt-get running")
    # 2. The power goes while dpkg unpacks Docker.
    cut_when(
        lab, start_deploy(lab, fresh_robot, host), host, DPKG_UNPACKS_DOCKER, "dpkg unpacking Docker", power_cut=True
    )
    assert lab.ok(host, "dpkg --audit; ls -A /var/lib/dpkg/updates").strip(), "dpkg was not left interrupted"
    # 3. The link drops once Docker is installed (daemon.json step or the release).
    cut_when(
        lab, start_deploy(lab, fresh_robot, host), host, DAEMON_JSON_OR_RELEASE, "the daemon.json step or the release"
    )
    wait_for(
        lambda: "update" not in lab.sh(host, "systemctl list-units --no-legend 'robot-payload-update-*'")[1],
        120,
        "a release left running to finish",
    )
    run = lab.provision("--limit", host, fleet=fresh_robot, label="(robot4 after the cuts)")
    assert run.returncode == 0, run.output[-4000:]
    assert lab.ok(host, "dpkg --audit; ls -A /var/lib/dpkg/updates").strip() == ""
    assert "install ok installed" in lab.ok(host, "dpkg-query -W -f '${Status}' docker-ce")
    daemon = json.loads(lab.ok(host, "cat /etc/docker/daemon.json"))
    assert daemon["insecure-registries"] == [lab.state["registry"]]
    assert (
        lab.sh(
            host,
            "ls /etc/docker/daemon.json.pending /etc/docker/.robotprov.* /etc/apt/keyrings/.robotprov.*"
            " /etc/apt/sources.list.d/.robotprov.* 2>/dev/null",
        )[1].strip()
        == ""
    )
    assert lab.version(host) == "1.0" and healthy(lab, host)
    converged(lab, host, "(robot4 converged)", fleet=fresh_robot)
