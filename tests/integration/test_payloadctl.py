"""The on-robot release helper payloadctl: its pure parts in process, the
rest as the zip application the robots get, run against stand-ins for docker
and systemctl (tests/integration/payloadrobot.py; the real thing runs end to
end): releases, rollbacks, the boot's recovery, the release store's upkeep."""

import json
import os
import socket
import subprocess
import sys

import pytest

from roles.payload import release
from roles.payload.payloadctl import durable, health
from roles.payload.payloadctl import lock as apply_lock
from roles.payload.payloadctl import releases as releases_module
from tests.integration.payloadrobot import FAKEBIN, FakeRobot, mode, store, switching


def test_wait_devices_names_the_missing_sensor(tmp_path, helper):
    present = tmp_path / "cam"
    present.write_text("")
    proc = subprocess.run(
        [helper, "wait-devices", "--timeout", "1", str(present), str(tmp_path / "lidar")],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 1 and proc.stderr.strip().endswith(str(tmp_path / "lidar"))


def test_result_reports_the_last_apply(tmp_path, helper):
    (tmp_path / "last-result.json").write_text(json.dumps({"ok": False, "message": "payload: release x failed"}))
    proc = subprocess.run(
        [sys.executable, helper, "result", "--dir", str(tmp_path), "--name", "robot-payload"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 1 and proc.stderr.strip() == "payload: release x failed"


def test_apply_finds_the_release_already_current(tmp_path, helper):
    """A second apply of the same spec (say, after a dropped link) changes nothing."""
    releases = store.Releases(str(tmp_path))
    (tmp_path / "releases" / "r1").mkdir(parents=True)
    releases.write_record("r1", {"id": "r1", "created": "x", "spec_hash": "abc", "state": "staged"})
    releases.point("current", "r1")
    spec = {
        "dir": str(tmp_path),
        "spec_hash": "abc",
        "autostart": False,
        "name": "robot-payload",
        "lock_file": str(tmp_path / "lock"),
        "compose": {"services": {}},
        "delivery": "pull",
        "health_timeout": 60,
        "stable_seconds": 1,
        "pull_timeout": 30,
        "apply_lock_timeout": 30,
        "keep_releases": 3,
        "checks": [],
        "takeover": {},
    }
    (tmp_path / "request.json").write_text(json.dumps({"spec": spec, "run": {}}))
    proc = subprocess.run(
        [sys.executable, helper, "apply", str(tmp_path / "request.json")], capture_output=True, text=True
    )
    assert proc.returncode == 0 and "release r1 is already current" in proc.stdout
    assert sorted(p.name for p in (tmp_path / "releases").iterdir()) == ["r1"]


def _stub_docker(tmp_path, monkeypatch, exec_exit: int):
    """A `docker` on PATH answering `ps` with one container and `exec` with
    ``exec_exit`` (no GPU exists on this machine to run the real check)."""
    stub = tmp_path / "docker"
    stub.write_text(
        "#!/bin/sh\n"
        'echo "$@" >> "$(dirname "$0")/calls"\n'
        'case "$1" in\n'
        "  ps) echo c0ffee ;;\n"
        "  inspect) exit 1 ;;\n"
        "  exec) echo 'NVIDIA-SMI has failed because it could not communicate with the NVIDIA driver' >&2; "
        f"exit {exec_exit} ;;\n"
        "esac\n"
    )
    stub.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path}:" + __import__("os").environ["PATH"])
    return tmp_path / "calls"


GPU_CHECK = {"command": ["nvidia-smi", "-L"], "failure": "cannot see a GPU"}  # what the gpu role adds


def test_gpu_check_fails_a_container_that_cannot_see_a_gpu(tmp_path, monkeypatch):
    calls = _stub_docker(tmp_path, monkeypatch, exec_exit=9)
    ok, why = health.run_checks("robot-payload", [GPU_CHECK])
    assert not ok and why.startswith("c0ffee cannot see a GPU (nvidia-smi -L failed: NVIDIA-SMI has failed")
    assert "exec c0ffee nvidia-smi -L" in calls.read_text()


def test_gpu_check_passes_and_is_skipped_without_a_command(tmp_path, monkeypatch):
    calls = _stub_docker(tmp_path, monkeypatch, exec_exit=0)
    assert health.run_checks("robot-payload", [GPU_CHECK]) == (True, "")
    assert health.run_checks("robot-payload", []) == (True, "")
    assert calls.read_text().count("exec") == 1


def test_healthy_release_is_recorded_private_and_reported_for_this_run(robot):
    robot.image("reg/ros/payload:1.1")
    result = robot.apply("reg/ros/payload:1.1", run_id="run-7")
    assert result.returncode == 0 and "is healthy" in result.stdout
    current, previous = robot.pointers()
    assert previous == "r1" and robot.releases.record(current)["state"] == "active"
    assert robot.releases.record(current)["run_id"] == "run-7" and "switch" not in robot.releases.record(current)
    assert mode(robot.releases.path(current)) == 0o700 and mode(robot.releases.dir) == 0o700
    assert mode(robot.releases.path(current, "compose.yaml")) == 0o600
    assert mode(robot.releases.path(current, "record.json")) == 0o600
    last = robot.root / "last-result.json"
    assert mode(last) == 0o600 and json.loads(last.read_text())["run_id"] == "run-7"
    assert not (robot.root / "runs" / "run-7").exists()  # the run's own files are gone once reported


@pytest.mark.parametrize(
    "behaviour, reason",
    [
        ("crash", "robot-payload-payload-1 is crash-looping"),  # containers are named as compose names them
        ("exit", "robot-payload-payload-1 exited with code 1"),
        ("unhealthy", "robot-payload-payload-1 is unhealthy: heartbeat check unhealthy"),
    ],
)
def test_broken_release_fails_at_once_and_the_old_one_runs_again(robot, behaviour, reason):
    robot.image("reg/ros/payload:bad", behaviour)
    # health_timeout is 600 s: waiting it out would hit the 30 s process bound.
    result = robot.apply("reg/ros/payload:bad")
    assert result.returncode == 1
    assert reason in result.stderr and "rolled back to r1 and it is running" in result.stderr
    assert "not healthy after" not in result.stderr
    assert robot.pointers() == ("r1", None)
    assert robot.state()["started"][-1] == "reg/ros/payload:1.0"
    failed = [r for r in robot.releases.all() if r != "r1"]
    assert [robot.releases.record(r)["state"] for r in failed] == ["failed"]
    assert robot.releases.record("r1")["rolled_back_from"]["reason"].startswith(reason)


def test_first_release_that_fails_stays_failed_so_the_next_run_tries_again(tmp_path, helper):
    robot = FakeRobot(tmp_path, helper)
    robot.image("reg/ros/payload:bad", "unhealthy")
    result = robot.apply("reg/ros/payload:bad")
    assert result.returncode == 1 and "no healthy release to roll back to (the next run tries again)" in result.stderr
    current, _ = robot.pointers()
    record = robot.releases.record(current)
    assert record["state"] == "failed"
    assert release.release_needed(record, record["spec_hash"], True, running=True)
    again = robot.apply("reg/ros/payload:bad", run_id="run-2")  # not "already current"
    assert again.returncode == 1 and "already current" not in again.stdout + again.stderr


def test_same_spec_with_the_payload_down_is_released_again(robot):
    state = robot.state()
    state["containers"] = {}
    robot.save(state)
    result = robot.apply("reg/ros/payload:1.0")
    assert result.returncode == 0 and "already current" not in result.stdout
    assert robot.state()["started"] == ["reg/ros/payload:1.0"]


def test_same_spec_running_is_already_current(robot):
    result = robot.apply("reg/ros/payload:1.0")
    assert result.returncode == 0 and "release r1 is already current" in result.stdout
    assert "started" not in robot.state()


def test_unreachable_registry_fails_within_the_pull_bound_and_keeps_the_old_release(robot):
    robot.image("reg/ros/payload:1.1", present=False, pull="fail")
    result = robot.apply("reg/ros/payload:1.1", pull_timeout=3)
    assert result.returncode == 1
    assert "cannot pull reg/ros/payload:1.1: Error response from daemon" in result.stderr
    assert "old release keeps running" in result.stderr
    assert robot.pointers() == ("r1", None) and robot.releases.all() == ["r1"]


def test_stalled_pull_is_cut_off_and_names_its_bound(robot):
    robot.image("reg/ros/payload:1.1", present=False, pull="hang")
    result = robot.apply("reg/ros/payload:1.1", pull_timeout=2)
    assert result.returncode == 1
    assert "docker pull reg/ros/payload:1.1 did not finish within 2 s (payload_pull_timeout)" in result.stderr
    assert robot.pointers() == ("r1", None)


def hold_apply_lock(robot, by):
    return apply_lock.Lock(str(robot.root), 0, {"by": by, "action": "apply"}).acquire()


@pytest.mark.parametrize("action", ["apply", "rollback"])
def test_a_second_deploy_waits_a_bounded_time_and_names_the_first(robot, action):
    robot.image("reg/ros/payload:1.1")
    robot.release("r0", "reg/ros/payload:1.1", created="r0")
    robot.releases.point("previous", "r0")
    robot.release("r1", "reg/ros/payload:1.0", spec={"apply_lock_timeout": 1})  # a rollback waits as the release says
    held = hold_apply_lock(robot, "alice@laptop (pyinfra)")
    try:
        if action == "apply":
            result = robot.apply("reg/ros/payload:1.1", apply_lock_timeout=1)
        else:
            result = robot.rollback("rb-1")
    finally:
        held.release()
    assert result.returncode == 1
    line = result.stderr.strip()
    assert line.startswith(f"payload: another deploy is running on {socket.gethostname()} since 20")
    assert line.endswith("(by alice@laptop (pyinfra)); gave up after 1 s (payload_apply_lock_timeout)")
    assert robot.pointers() == ("r1", "r0") and "started" not in robot.state()


def test_rollback_switches_to_the_previous_release_when_it_is_healthy(robot):
    robot.image("reg/ros/payload:0.9")
    robot.release("r0", "reg/ros/payload:0.9", created="r0")
    robot.releases.point("previous", "r0")
    result = robot.rollback()
    assert result.returncode == 0 and "rolled back from r1 to r0" in result.stdout
    assert robot.pointers() == ("r0", "r1") and robot.releases.record("r0")["state"] == "active"


def test_failed_rollback_is_undone_and_the_old_release_started_again(robot):
    robot.image("reg/ros/payload:0.9", "crash")
    robot.release("r0", "reg/ros/payload:0.9", created="r0")
    robot.releases.point("previous", "r0")
    result = robot.rollback()
    assert result.returncode == 1
    assert "rollback to r0 failed (robot-payload-payload-1 is crash-looping" in result.stderr
    assert "restored r1 and it is running" in result.stderr
    assert robot.pointers() == ("r1", "r0")
    assert robot.state()["started"] == ["reg/ros/payload:0.9", "reg/ros/payload:1.0"]
    record = robot.releases.record("r0")
    assert record["state"] == "active" and "switch" not in record
    assert "crash-looping" in record["rollback_failed"]["reason"]


def test_boot_undoes_a_release_a_power_cut_left_unverified(robot):
    robot.image("reg/ros/payload:1.1")
    switching(robot, "r2", "reg/ros/payload:1.1", "apply", "r1", "r0")
    robot.releases.point("previous", "r1")
    robot.releases.point("current", "r2")
    proc = robot.payloadctl("start", "--dir", str(robot.root), "--name", "robot-payload")
    assert proc.returncode == 0, proc.stderr
    assert robot.pointers() == ("r1", "r0")
    assert robot.releases.record("r2")["state"] == "failed" and "interrupted" in robot.releases.record("r2")["reason"]
    assert robot.state()["compose_up"][-5:] == [
        "-f",
        str(robot.root / "current" / "compose.yaml"),
        "up",
        "-d",
        "--remove-orphans",
    ]


def test_boot_undoes_an_interrupted_rollback(robot):
    robot.image("reg/ros/payload:0.9")
    switching(robot, "r0", "reg/ros/payload:0.9", "rollback", "r1", "r0", prior_state="active")
    robot.releases.point("current", "r0")
    robot.releases.point("previous", "r1")
    robot.payloadctl("start", "--dir", str(robot.root), "--name", "robot-payload")
    assert robot.pointers() == ("r1", "r0") and robot.releases.record("r0")["state"] == "active"


def test_boot_runs_an_unverified_first_release_for_the_deploy_to_verify(tmp_path, helper):
    robot = FakeRobot(tmp_path, helper)
    robot.image("reg/ros/payload:1.0")
    switching(robot, "r1", "reg/ros/payload:1.0", "apply", None, None)
    robot.releases.point("current", "r1")
    durable.write_text(
        robot.releases.path("r1", "compose.yaml"),
        store.compose_yaml(
            releases_module.release_compose(
                {
                    "name": "robot-payload",
                    "services": {"payload": {"image": "reg/ros/payload:1.0", "restart": "always"}},
                }
            )
        ),
    )
    robot.payloadctl("start", "--dir", str(robot.root), "--name", "robot-payload")
    assert robot.pointers() == ("r1", None) and robot.releases.record("r1")["state"] == "switching"
    assert "compose_up" in robot.state()
    assert robot.state()["started_policies"] == [["reg/ros/payload:1.0", "no"]]  # unverified: no policy, one compose up
    assert "docker update --restart always robot-payload-payload-1" not in robot.state()["log"]


def test_start_leaves_the_switch_to_an_apply_that_holds_the_lock(robot):
    robot.image("reg/ros/payload:1.1")
    switching(robot, "r2", "reg/ros/payload:1.1", "apply", "r1", None)
    robot.releases.point("current", "r2")
    held = hold_apply_lock(robot, "ops")
    try:
        robot.payloadctl("start", "--dir", str(robot.root), "--name", "robot-payload")
    finally:
        held.release()
    assert robot.pointers()[0] == "r2" and robot.releases.record("r2")["state"] == "switching"


def test_gc_keeps_the_newest_releases_current_previous_and_their_images(tmp_path, helper):
    robot = FakeRobot(tmp_path, helper)
    for n in range(1, 7):
        robot.image(f"reg/p:{n}")
        robot.release(f"r{n}", f"reg/p:{n}", created=f"2026-01-0{n}")
    robot.release("r7", "reg/p:4", created="2026-01-07")  # shares r4's image
    robot.releases.point("current", "r2")  # rolled back far: current and previous are old ones
    robot.releases.point("previous", "r1")
    env = dict(os.environ, PATH=f"{FAKEBIN}:{os.environ['PATH']}", FAKE_STATE=str(robot.state_path))
    code = (
        "import sys; sys.path.insert(0, sys.argv[1]); from payloadctl import releases; "
        "releases.gc(3, releases.Releases(sys.argv[2]))"
    )
    subprocess.run([sys.executable, "-c", code, helper, str(robot.root)], env=env, check=True)
    assert sorted(robot.releases.all()) == ["r1", "r2", "r5", "r6", "r7"]
    removed = [line for line in robot.state()["log"] if line.startswith("docker image rm")]
    assert sorted(removed) == ["docker image rm reg/p:3"]  # reg/p:4 is still used by r7


def test_result_of_a_run_that_recorded_nothing_fails_with_a_clear_line(tmp_path, helper):
    (tmp_path / "last-result.json").write_text(
        json.dumps({"ok": True, "message": "payload: release old is healthy", "run_id": "earlier"})
    )
    proc = subprocess.run(
        [sys.executable, helper, "result", "--dir", str(tmp_path), "--name", "robot-payload", "--run-id", "this-run"],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 1 and "healthy" not in proc.stdout
    assert proc.stderr.startswith("payload: payloadctl recorded no result for this run (this-run): disk full?")


# --- the apply lock is root's alone (issue 17, item 2) ---------------------------
