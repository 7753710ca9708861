"""End to end: faults during a payload release, injected on the simulated
fleet (issue 7).  Whatever fails, the robot ends on a healthy release, the run
says what happened, and a rerun converges, then reports no change.

Each test owns one robot and leaves it on the lab fleet's release (1.0), so
the modules that run after this one find the fleet as provisioned.  Power
cuts (`docker kill` + `docker start` of the host container) are grouped on
robot2 so the suite pays for few boots.
"""

from __future__ import annotations

import json
import subprocess

import pytest

from tests.e2e.conftest import wait_for
from tests.e2e.faults import DIR, HEALTH_WAIT, NEW_CONTAINERS, Background, build_image_with_a_new_layer, image

pytestmark = pytest.mark.e2e

STALL_PORT = 5999  # a "registry" on the robot that accepts connections and never answers


def host_settings(host: str, *lines: str) -> dict[str, str]:
    """A fleet_with() replacement adding settings to one robot."""
    extra = "".join(f"      {line}\n" for line in lines)
    return {f"    {host}:\n      udev_sensors:": f"    {host}:\n{extra}      udev_sensors:"}


def line_of(run, host: str, text: str) -> str:
    lines = [line for line in run.output.splitlines() if f"[{host}]" in line and text in line]
    assert lines, f"no line with {text!r} for {host} in:\n{run.output[-3000:]}"
    return lines[0]


def releases(lab, host: str) -> list[str]:
    return lab.ok(host, f"ls {DIR}/releases").split()


def healthy(lab, host: str) -> bool:
    return lab.payload(host)["State"].get("Health", {}).get("Status") == "healthy"


def converges(lab, host: str, fleet=None):
    """The lab fleet (or `fleet`) reruns clean: a change at most, then none."""
    run = lab.provision("--limit", host, fleet=fleet, label=f"({host} converges)")
    assert run.returncode == 0, run.output[-3000:]
    again = lab.provision("--limit", host, fleet=fleet, label=f"({host} converged)")
    assert again.returncode == 0 and again.changed_hosts == set(), again.output[-3000:]
    assert healthy(lab, host) and lab.record(host)["state"] == "active"


def start_stalled_registry(lab, host: str):
    code = (
        "import socket; s = socket.socket(); s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1); "
        f"s.bind(('127.0.0.1', {STALL_PORT})); s.listen(64); held = []; "
        "[held.append(s.accept()) for _ in iter(int, 1)]"
    )
    lab.ok(host, f'systemd-run --unit=stalled-registry python3 -c "{code}"')
    connect = f"python3 -c \"import socket; socket.create_connection(('127.0.0.1', {STALL_PORT}))\""
    wait_for(lambda: lab.sh(host, connect)[0] == 0, 10, "the stalled registry to listen")


def stop_stalled_registry(lab, host: str):
    lab.sh(host, "systemctl stop stalled-registry; systemctl reset-failed stalled-registry")


def cut_power(lab, host: str, when: str):
    """Wait on the robot until the shell condition `when` holds, then pull the
    plug (SIGKILL the host container) and switch it on again."""
    lab.ok(host, f"for i in $(seq 1200); do {when} && exit 0; sleep 0.05; done; exit 1")
    container = f"{lab.prefix}-{host}"
    subprocess.run(["docker", "kill", container], check=True, capture_output=True)
    subprocess.run(["docker", "start", container], check=True, capture_output=True)
    wait_for(
        lambda: lab.sh(host, "systemctl is-active robot-payload")[1].strip() == "active",
        180,
        f"robot-payload.service to start at boot on {host}",
    )
    wait_for(lambda: healthy(lab, host), 90, f"the payload on {host} to be healthy after boot")


STARTED_SINCE_BOOT = (
    "docker events --since $(( $(date +%s) - 3600 )) --until $(date +%s.%N) --filter event=start"
    " --filter label=com.docker.compose.project=robot-payload --filter label=org.opencontainers.image.version={version}"
    " --format '{{{{.ID}}}}'"
)  # Docker keeps its events in memory: only this boot's


def test_a_failing_update_leaves_the_old_release_running_and_says_why(lab, first_run, tmp_path):
    """robot1: crash loop, missing tag, unreachable registry, stalled pull,
    then the payload stopped behind the unit's back."""
    host = "robot1"
    old = lab.record(host)["id"]

    def attempt(label: str, **replacements):
        path = tmp_path / label.replace(" ", "-")
        path.mkdir()
        run = lab.provision("--limit", host, fleet=lab.fleet_with(path, **replacements), label=f"({host}: {label})")
        assert run.returncode != 0, run.output[-3000:]  # (one host failed: pyinfra prints no --json)
        assert lab.record(host)["id"] == old and lab.version(host) == "1.0" and healthy(lab, host)
        return run

    run = attempt("crash loop", **host_settings(host, "payload_command: [/bin/sh, -c, 'echo boom; exit 3']"))
    line = line_of(run, host, "payload: release")
    # Unverified, the release runs with no restart policy (payloadctl gives it once healthy): it exits, never restarts.
    assert "exited with code 3" in line and "crash-looping" not in line, line
    assert f"rolled back to {old} and it is running" in line and "not healthy after" not in line

    run = attempt("missing tag", **image("9.9-does-not-exist"))
    assert "cannot pull" in line_of(run, host, "payload:") and "the old release keeps running" in run.output

    run = attempt("registry unreachable", **image("127.0.0.1:9/ros/payload:1.1"))
    assert "cannot pull 127.0.0.1:9/ros/payload:1.1" in line_of(run, host, "payload:")

    start_stalled_registry(lab, host)
    try:
        run = attempt(
            "stalled pull",
            **image(f"127.0.0.1:{STALL_PORT}/ros/payload:1.1"),
            **host_settings(host, "payload_pull_timeout: 5"),
        )
        assert "did not finish within 5 s (payload_pull_timeout)" in line_of(run, host, "payload:")
    finally:
        stop_stalled_registry(lab, host)

    # The oneshot unit stays "active" when the containers are gone.
    lab.ok(host, "docker ps -q --filter label=com.docker.compose.project=robot-payload | xargs docker stop")
    assert lab.ok(host, "systemctl is-active robot-payload").strip() == "active"
    run = lab.provision("--limit", host, label=f"({host}: payload down)")
    assert run.returncode == 0 and run.changed_hosts == {host}, run.output[-3000:]
    converges(lab, host)


def test_two_deploys_at_once_are_serialized(lab, first_run, tmp_path):
    host = "robot1"
    before = set(releases(lab, host))
    fleet = lab.fleet_with(tmp_path, **image("1.1"))
    both = [Background(lab, "--limit", host, fleet=fleet) for _ in range(2)]
    results = [b.wait() for b in both]
    assert [code for code, _ in results] == [0, 0], results
    assert lab.version(host) == "1.1" and healthy(lab, host)
    assert len(set(releases(lab, host)) - before) == 1  # one release, not two

    # A deploy that cannot get the robot within its bound says who holds it.
    start_stalled_registry(lab, host)
    (tmp_path / "stalled").mkdir()
    (tmp_path / "bounded").mkdir()
    holder = Background(
        lab,
        "--limit",
        host,
        fleet=lab.fleet_with(tmp_path / "stalled", **image(f"127.0.0.1:{STALL_PORT}/ros/payload:1.1")),
    )
    try:
        wait_for(
            lambda: lab.sh(host, f"test -s {DIR}/lock/owner.json && pgrep -f 'docker [p]ull'")[0] == 0,
            120,
            "the first deploy to hold the robot",
        )
        bounded = lab.fleet_with(tmp_path / "bounded", **host_settings(host, "payload_apply_lock_timeout: 3"))
        run = lab.provision("--limit", host, fleet=bounded, label=f"({host}: while another deploy runs)")
        assert run.returncode != 0
        # Said when the run starts (from the snapshot), then the refusal once the wait ran out.
        assert line_of(run, host, "another deploy is running").endswith("; waiting")
        line = line_of(run, host, "gave up after")
        assert f"another deploy is running on {host} since 20" in line and "(by " in line
        assert "gave up after 3 s (payload_apply_lock_timeout)" in line
    finally:
        stop_stalled_registry(lab, host)
        code, output = holder.wait(120)
    assert code != 0 and "cannot pull" in output
    assert lab.version(host) == "1.1" and healthy(lab, host)
    converges(lab, host)  # back to the lab fleet's 1.0


def test_first_release_failing_and_a_full_disk(lab, first_run, tmp_path):
    host = "robot3"
    # A robot that never had a release.
    lab.ok(host, f"systemctl stop robot-payload && rm -rf {DIR}/current {DIR}/previous {DIR}/releases")
    broken = lab.fleet_with(tmp_path, **image("1.2-broken"))
    for attempt in ("first release, broken", "broken again"):
        run = lab.provision("--limit", host, fleet=broken, label=f"({host}: {attempt})")
        assert run.returncode != 0, run.output[-3000:]
        line = line_of(run, host, "payload: release")
        assert "unhealthy" in line and "no healthy release to roll back to (the next run tries again)" in line
        assert lab.record(host)["state"] == "failed"
    assert len(releases(lab, host)) == 2  # the rerun tried again instead of calling it converged
    converges(lab, host)
    good = lab.record(host)["id"]

    # Disk full while the release is written: one free page holds this run's
    # spec, nothing more (a tmpfs over the payload directory).
    kept = releases(lab, host)
    lab.ok(
        host,
        f"mkdir -p /run/payload-copy && cp -a {DIR}/. /run/payload-copy/ &&"
        f" mount -t tmpfs -o size=2m,mode=755 full {DIR} && cp -a /run/payload-copy/. {DIR}/ &&"
        f" (dd if=/dev/zero of={DIR}/.filler bs=4k 2>/dev/null; truncate -s -4K {DIR}/.filler)",
    )
    try:
        run = lab.provision(
            "--limit", host, fleet=_fleet(lab, tmp_path, "full", **image("1.1")), label=f"({host}: disk full)"
        )
        assert run.returncode != 0
        assert "payloadctl recorded no result for this run" in line_of(run, host, "disk full?")
        assert "is healthy" not in run.output
        assert releases(lab, host) == kept  # nothing half-written left behind
    finally:
        lab.ok(host, f"umount {DIR} && rm -rf /run/payload-copy")
    assert lab.record(host)["id"] == good and lab.version(host) == "1.0" and healthy(lab, host)

    # Disk full while the image is pulled (docker downloads into its tmp dir).
    tag = build_image_with_a_new_layer(lab)
    lab.ok(host, "mkdir -p /var/lib/docker/tmp && mount -t tmpfs -o size=64k full /var/lib/docker/tmp")
    try:
        run = lab.provision(
            "--limit", host, fleet=_fleet(lab, tmp_path, "pull", **image(tag)), label=f"({host}: disk full during pull)"
        )
        assert run.returncode != 0
        line = line_of(run, host, "cannot pull")
        assert "no space left on device" in line.lower() and "the old release keeps running" in line
    finally:
        lab.ok(host, "umount /var/lib/docker/tmp")
    assert lab.record(host)["id"] == good and lab.version(host) == "1.0" and healthy(lab, host)
    converges(lab, host)


def _fleet(lab, tmp_path, name: str, **replacements):
    path = tmp_path / name
    path.mkdir()
    return lab.fleet_with(path, **replacements)


def test_power_cuts_during_a_release_and_a_rollback(lab, first_run, tmp_path):
    host = "robot2"
    converges(lab, host)  # on the lab fleet's 1.0 whatever ran before
    old = lab.record(host)["id"]

    # During the pull: nothing was switched, the old release boots.
    start_stalled_registry(lab, host)
    deploy = Background(
        lab, "--limit", host, fleet=_fleet(lab, tmp_path, "stalled", **image(f"127.0.0.1:{STALL_PORT}/ros/payload:1.1"))
    )
    try:
        cut_power(lab, host, "pgrep -f 'docker [p]ull' >/dev/null")
    finally:
        deploy.kill()
    assert lab.record(host)["id"] == old and lab.version(host) == "1.0"

    # As the one compose up that switches creates the new release's
    # containers, stops the old ones and starts the new: they have no
    # restart policy, so Docker starts none of them at boot, and the boot
    # goes back to the last verified release.
    to_11 = _fleet(lab, tmp_path, "to-1.1", **image("1.1"))
    deploy = Background(lab, "--limit", host, fleet=to_11)
    try:
        cut_power(lab, host, NEW_CONTAINERS.format(version="1.1"))
    finally:
        deploy.kill()
    assert lab.record(host)["id"] == old and lab.version(host) == "1.0"
    assert "interrupted before it was verified healthy" in lab.record(host)["rolled_back_from"]["reason"]
    assert lab.ok(host, STARTED_SINCE_BOOT.format(version="1.1")).strip() == ""

    # During the health wait (right after the switch): the boot must not run
    # the unverified release; it goes back to the last verified one.
    deploy = Background(lab, "--limit", host, fleet=to_11)
    try:
        cut_power(lab, host, HEALTH_WAIT)
    finally:
        deploy.kill()
    assert lab.record(host)["id"] == old and lab.version(host) == "1.0"
    interrupted = lab.record(host)["rolled_back_from"]
    assert "interrupted before it was verified healthy" in interrupted["reason"]
    assert json.loads(lab.ok(host, f"cat {DIR}/releases/{interrupted['id']}/record.json"))["state"] == "failed"
    converges(lab, host, to_11)  # the rerun releases 1.1 again, under the health gate
    on_11 = lab.record(host)["id"]

    # During a manual rollback: the boot undoes it (1.1 was the verified one).
    rollback = Background(lab, "--limit", host, script="rollback.py")
    try:
        cut_power(lab, host, HEALTH_WAIT)
    finally:
        rollback.kill()
    assert lab.record(host)["id"] == on_11 and lab.version(host) == "1.1"
    assert lab.record(host, "previous")["state"] == "active"
    converges(lab, host)  # back to the lab fleet's 1.0
