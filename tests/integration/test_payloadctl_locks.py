"""payloadctl (tests/integration/payloadrobot.py): its apply lock, an update
the boot interrupted, what an interrupted compose up left, and the restart
policy a release gets only once it is verified."""

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from roles.payload.payloadctl import durable
from roles.payload.payloadctl import lock as apply_lock
from roles.payload.payloadctl import releases as releases_module
from tests.integration.payloadrobot import FakeRobot, mode, store, switching, wait_until

NOBODY = 65534


def as_nobody(code: str) -> subprocess.CompletedProcess:
    def drop():
        os.setgid(NOBODY)
        os.setuid(NOBODY)

    return subprocess.run(["/usr/bin/python3", "-c", code], capture_output=True, text=True, preexec_fn=drop, timeout=30)


def test_no_other_user_can_open_the_apply_lock(robot):
    """flock works on a read-only descriptor: a lock file another user can
    open is one they can hold, blocking every deploy and the boot recovery."""
    assert robot.apply("reg/ros/payload:1.0", run_id="run-0").returncode == 0
    held = apply_lock.Lock(str(robot.root))
    assert mode(held.dir) == 0o700 and mode(held.path) == 0o600
    # A payload directory any user may enter, as /var/lib/robot-payload is.
    root = tempfile.mkdtemp(prefix="robotprov-lock-", dir="/tmp")
    try:
        os.chmod(root, 0o755)
        lock = apply_lock.Lock(root).acquire(blocking=False)
        lock.release()
        probe = as_nobody(f"import fcntl; fcntl.flock(open({lock.path!r}), fcntl.LOCK_EX); print('held')")
        assert probe.returncode != 0 and "PermissionError" in probe.stderr, probe.stdout + probe.stderr
    finally:
        shutil.rmtree(root)


def test_a_lock_held_by_a_process_that_is_not_ours_is_named_as_such(robot):
    held = apply_lock.Lock(str(robot.root))
    held.acquire(blocking=False)
    held.release()  # made the directory and file; the finished deploy's note is gone
    assert not os.path.exists(held.owner_path)
    # An earlier deploy's note left behind must not be taken for the holder either.
    durable.write_json(held.owner_path, {"by": "old@laptop (pyinfra)", "since": "2026-01-01T00:00:00Z", "pid": 1})
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            f"import fcntl, time; f = open({held.path!r}); "
            "fcntl.flock(f, fcntl.LOCK_EX); print('held', flush=True); time.sleep(30)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        robot.image("reg/ros/payload:1.1")
        result = robot.apply("reg/ros/payload:1.1", apply_lock_timeout=1)
    finally:
        holder.kill()
        holder.wait()
    line = result.stderr.strip()
    assert result.returncode == 1
    assert f"is held by process {holder.pid} ({sys.executable} -c import fcntl" in line, line
    assert line.endswith("which is not a deploy of this tool; gave up after 1 s (payload_apply_lock_timeout)")
    assert "old@laptop" not in line


# --- boot recovery and deploys never at once (issue 21) -----------------------------


def interrupted_update(robot):
    """A power cut during the health wait of an update from 1.0 (r1) to 1.1 (r2)."""
    robot.image("reg/ros/payload:1.1")
    switching(robot, "r2", "reg/ros/payload:1.1", "apply", "r1", None)
    robot.releases.point("previous", "r1")
    robot.releases.point("current", "r2")


def test_a_deploy_waits_for_the_boot_recovery_and_says_so(robot):
    """The boot holds the lock until its compose up is done: a deploy that
    arrives meanwhile waits (it used to restart the unit mid-recreate)."""
    interrupted_update(robot)
    boot = subprocess.Popen(
        [sys.executable, robot.helper, "start", "--dir", str(robot.root), "--name", "robot-payload"],
        env=robot.env(FAKE_COMPOSE_SLEEP="3"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        wait_until(lambda: "compose_up" in robot.state(), "the boot's compose up to begin")
        deploy = robot.payloadctl("apply", robot.spec("reg/ros/payload:1.1", "run-9"), "--run-id", "run-9")
        result = robot.result("run-9")
    finally:
        boot.wait(timeout=30)
    assert f"payload: {socket.gethostname()} is recovering from an interrupted release since 20" in deploy.stderr
    assert deploy.stderr.rstrip().splitlines()[0].endswith("; waiting")
    assert result.returncode == 0 and "is healthy" in result.stdout
    log = robot.state()["log"]
    boot_up = max(
        i
        for i, line in enumerate(log)
        if "current/compose.yaml up -d --remove-orphans" in line
        and "--no-start" not in line
        and i < log.index("docker pull -q reg/ros/payload:1.1")
    )
    assert boot_up < log.index("docker pull -q reg/ros/payload:1.1")  # the deploy began once the boot was done
    assert robot.releases.record("r2")["state"] == "failed"  # the boot decided: back on r1
    assert robot.releases.record(robot.pointers()[0])["state"] == "active"  # and the deploy finished the update


def test_what_an_interrupted_compose_up_left_is_removed_before_the_next(robot):
    """A recreate cut short leaves the old container renamed <id>_<name> and
    the new one not started; the next compose up failed on the name."""
    state = robot.state()
    state["containers"] = {
        "0123456789ab_robot-payload-payload-1": {
            "image": "reg/ros/payload:1.0",
            "project": "robot-payload",
            "name": "0123456789ab_robot-payload-payload-1",
            "running": False,
            "status": "exited",
        },
        "robot-payload-payload-1": {
            "image": "reg/ros/payload:1.0",
            "name": "robot-payload-payload-1",
            "running": False,
            "status": "created",
        },
    }
    robot.save(state)
    boot = robot.payloadctl("start", "--dir", str(robot.root), "--name", "robot-payload")
    assert boot.returncode == 0, boot.stdout + boot.stderr
    assert (
        "removed what an interrupted compose up left: 0123456789ab_robot-payload-payload-1, robot-payload-payload-1"
    ) in boot.stderr
    assert list(robot.state()["containers"]) == ["robot-payload-payload-1"]
    assert robot.state()["containers"]["robot-payload-payload-1"]["running"] is True


def test_an_unverified_release_has_no_restart_policy_until_it_is_verified(robot):
    """After a power cut Docker brings back what has a restart policy: the
    new release's containers must not come back before the boot recovery
    decides which release runs.  Its file grants none (the policy waits in
    x-restart-when-verified), so one compose up creates and starts it
    without one, and the policy is given once it is verified."""
    robot.image("reg/ros/payload:1.1")
    compose = {
        "name": "robot-payload",
        "services": {"payload": {"image": "reg/ros/payload:1.1", "restart": "unless-stopped"}},
    }
    result = robot.apply("reg/ros/payload:1.1", compose=compose)
    assert result.returncode == 0
    log = robot.state()["log"]
    up = [i for i, line in enumerate(log) if "compose" in line and " up " in line + " "]
    assert len(up) == 1 and "--no-start" not in log[up[0]]  # created, old one stopped, new one started: one call
    assert robot.state()["started_policies"] == [["reg/ros/payload:1.1", "no"]]  # never started with a policy
    verified = log.index("docker update --restart unless-stopped robot-payload-payload-1")
    assert up[0] < verified
    assert robot.state()["containers"]["robot-payload-payload-1"]["policy"] == "unless-stopped"
    written = json.loads(Path(robot.releases.path(robot.pointers()[0], "compose.yaml")).read_text().split("\n", 1)[1])
    assert written["services"]["payload"]["restart"] == "no"
    assert written["x-restart-when-verified"] == {"payload": "unless-stopped"}


def test_an_unverified_release_an_older_payloadctl_wrote_is_created_then_stripped_of_its_policy(tmp_path, helper):
    """A file that names its policies itself (written before the policies
    moved to x-restart-when-verified): at boot, a first release left
    unverified is created, given policy `no`, then started."""
    robot = FakeRobot(tmp_path, helper)
    robot.image("reg/ros/payload:1.0")
    switching(robot, "r1", "reg/ros/payload:1.0", "apply", None, None)
    compose = {"name": "robot-payload", "services": {"payload": {"image": "reg/ros/payload:1.0", "restart": "always"}}}
    durable.write_text(robot.releases.path("r1", "compose.yaml"), store.compose_yaml(compose))
    robot.releases.point("current", "r1")
    assert robot.payloadctl("start", "--dir", str(robot.root), "--name", "robot-payload").returncode == 0
    log = robot.state()["log"]
    up = [i for i, line in enumerate(log) if "compose" in line and " up " in line + " "]
    no_policy = log.index("docker update --restart no robot-payload-payload-1")
    assert len(up) == 2 and "--no-start" in log[up[0]] and up[0] < no_policy < up[1]
    assert robot.state()["started_policies"] == [["reg/ros/payload:1.0", "no"]]
    assert robot.releases.record("r1")["state"] == "switching"  # still for the next deploy to verify


@pytest.mark.parametrize(
    "written",
    [releases_module.release_compose, lambda doc: doc],
    ids=["this payloadctl's file", "an older payloadctl's"],
)
def test_the_boot_gives_a_verified_release_its_restart_policy_back(robot, written):
    """A power cut between the verdict and the policy: the boot restores it."""
    state = robot.state()
    state["containers"]["robot-payload-payload-1"]["policy"] = "no"
    robot.save(state)
    compose = {"name": "robot-payload", "services": {"payload": {"image": "reg/ros/payload:1.0", "restart": "always"}}}
    durable.write_text(robot.releases.path("r1", "compose.yaml"), store.compose_yaml(written(compose)))
    assert robot.payloadctl("start", "--dir", str(robot.root), "--name", "robot-payload").returncode == 0
    assert robot.state()["containers"]["robot-payload-payload-1"]["policy"] == "always"


# --- takeover touches only the payload (issue 17, item 3) ---------------------------
