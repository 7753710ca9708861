"""The on-robot release helper payloadctl: its pure parts in process, the
rest as the zip application the robots get, run against stand-ins for docker
and systemctl (the real thing runs end to end)."""

import json
import subprocess
import sys

import pytest

from roles.payload import release
from roles.payload.payloadctl import durable, health, lifecycle
from roles.payload.payloadctl import lock as apply_lock
from roles.payload.payloadctl import releases as releases_module


class store:
    """The release store as these tests set it up: records and pointers
    written straight to disk (a state payloadctl then finds), read back raw."""

    compose_yaml = staticmethod(releases_module.compose_yaml)

    class Releases(releases_module.Releases):
        def write_record(self, rid, record):
            durable.write_json(self.path(rid, "record.json"), record)

        def point(self, name, rid):
            lifecycle.Life(self)._point(name, rid)

        record = releases_module.Releases.raw_record


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


# --- payloadctl against a fake `docker` and `systemctl` ------------------------
# payloadctl is stdlib-only and shells out to docker and systemctl; the tests
# put small stand-ins first on PATH (tests/unit/fakebin) that answer from a
# JSON state file, and run the real helper as a process.

import os  # noqa: E402
import shutil  # noqa: E402
import socket  # noqa: E402
import stat  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

FAKEBIN = Path(__file__).resolve().parent / "fakebin"
SPEC = {
    "name": "robot-payload",
    "autostart": True,
    "delivery": "pull",
    "health_timeout": 600,
    "stable_seconds": 1,
    "keep_releases": 3,
    "pull_timeout": 30,
    "apply_lock_timeout": 30,
    "checks": [],
    "takeover": {"primary": "reg/ros/payload", "container": [], "project": []},
}


def spec_hash(ref):
    return "h" + ref.replace("/", "-").replace(":", "-")


class FakeRobot:
    def __init__(self, tmp_path, helper):
        self.root = tmp_path / "payload"
        self.root.mkdir()
        self.helper = helper
        self.state_path = tmp_path / "state.json"
        self.releases = store.Releases(str(self.root))
        self.save({"root": str(self.root), "images": {}, "containers": {}, "log": []})

    def state(self):
        return json.loads(self.state_path.read_text())

    def save(self, state):
        self.state_path.write_text(json.dumps(state))

    def image(self, ref, behaviour="healthy", present=True, pull="ok", platform="linux/amd64"):
        state = self.state()
        state["images"][ref] = {
            "id": "sha256:" + ref.replace(":", "-").replace("/", "-"),
            "behaviour": behaviour,
            "present": present,
            "pull": pull,
            "platform": platform,
        }
        self.save(state)

    def architecture(self, arch):
        state = self.state()
        state["arch"] = arch
        self.save(state)

    def spec_fields(self, ref, **extra):
        return {
            **SPEC,
            "dir": str(self.root),
            "spec_hash": spec_hash(ref),
            "lock_file": str(self.root / "update.lock"),
            "compose": {"name": "robot-payload", "services": {"payload": {"image": ref}}},
            **extra,
        }

    def release(self, rid, ref, state="active", created=None, spec=None, **extra):
        """A release already on the robot (``spec``: what differs in its spec)."""
        durable.make_private_dir(self.releases.path(rid))
        doc = {"name": "robot-payload", "services": {"payload": {"image": ref}}}
        durable.write_text(self.releases.path(rid, "compose.yaml"), store.compose_yaml(doc))
        durable.write_json(self.releases.path(rid, "spec.json"), self.spec_fields(ref, **(spec or {})))
        image_id = self.state()["images"][ref]["id"]
        self.releases.write_record(
            rid,
            {
                "id": rid,
                "created": created or rid,
                "spec_hash": spec_hash(ref),
                "state": state,
                "autostart": True,
                "images": {ref: {"id": image_id, "pinned": ref}},
                **extra,
            },
        )

    def running(self, ref):
        state = self.state()
        state["containers"] = {
            "robot-payload-payload-1": {
                "image": ref,
                "looks": 5,
                "name": "robot-payload-payload-1",
                "service": "payload",
                "policy": "unless-stopped",
            }
        }
        state["unit_active"] = True
        self.save(state)

    def spec(self, ref, run_id="run-1", **extra):
        request = {
            "spec": self.spec_fields(ref, **extra),
            "run": {"by": "ops@laptop (pyinfra)", "force": False, "host": "pi1"},
        }
        path = self.root.parent / f"spec-{run_id}.json"
        path.write_text(json.dumps(request))
        return str(path)

    def payloadctl(self, *args, timeout=30):
        return subprocess.run(
            [sys.executable, self.helper, *args], env=self.env(), capture_output=True, text=True, timeout=timeout
        )

    def env(self, **more):
        return dict(
            os.environ,
            PATH=f"{FAKEBIN}:{os.environ['PATH']}",
            FAKE_STATE=str(self.state_path),
            FAKE_HELPER=self.helper,
            **more,
        )

    def apply(self, ref, run_id="run-1", **extra):
        self.payloadctl("apply", self.spec(ref, run_id, **extra), "--run-id", run_id)
        return self.result(run_id)

    def rollback(self, run_id="rb-1", *more):
        self.payloadctl("rollback", "--dir", str(self.root), "--run-id", run_id, *more)
        return self.result(run_id)

    def result(self, run_id):
        return self.payloadctl("result", "--dir", str(self.root), "--name", "robot-payload", "--run-id", run_id)

    def pointers(self):
        return self.releases.pointer("current"), self.releases.pointer("previous")


def mode(path):
    return stat.S_IMODE(os.lstat(path).st_mode)


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


def switching(robot, rid, ref, kind, came_from, previous_before, **extra):
    robot.release(
        rid,
        ref,
        state="switching",
        created=rid,
        switch={"kind": kind, "from": came_from, "previous_before": previous_before, **extra},
    )


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


def wait_until(predicate, what, seconds=10):
    import time

    deadline = time.time() + seconds
    while time.time() < deadline:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


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


def test_takeover_stops_an_earlier_copy_of_the_payload_and_no_other_projects_container(robot):
    """A service of ours uses a common image (a broker): another compose
    project's broker of that image stays as it is; the payload started by
    hand is taken over, and the record says why."""
    robot.image("reg/ros/payload:1.1")
    robot.image("reg/lib/mosquitto:2")
    state = robot.state()
    state["containers"].update(
        {
            "homeauto-broker-1": {
                "image": "reg/lib/mosquitto:2",
                "name": "homeauto-broker-1",
                "project": "homeauto",
                "service": "broker",
                "policy": "always",
            },
            "ros_payload": {"image": "reg/ros/payload:1.1", "name": "ros_payload", "project": None, "policy": "always"},
        }
    )
    robot.save(state)
    compose = {
        "name": "robot-payload",
        "services": {"payload": {"image": "reg/ros/payload:1.1"}, "broker": {"image": "reg/lib/mosquitto:2"}},
    }
    result = robot.apply("reg/ros/payload:1.1", compose=compose)
    assert result.returncode == 0, result.stderr
    containers = robot.state()["containers"]
    assert (
        containers["homeauto-broker-1"].get("running", True) and containers["homeauto-broker-1"]["policy"] == "always"
    )
    assert not containers["ros_payload"]["running"] and containers["ros_payload"]["policy"] == "no"
    taken = robot.releases.record(robot.pointers()[0])["taken_over"]
    assert [(c["name"], c["why"]) for c in taken] == [("ros_payload", "it runs the payload's image")]


def test_text_the_robot_controls_reaches_the_operator_as_one_printable_line(robot):
    """A healthcheck's output is the image's to write: an escape sequence or
    a newline in it is shown, never obeyed by the operator's terminal."""
    state = robot.state()
    state["images"]["reg/ros/payload:evil"] = {
        "id": "sha256:evil",
        "behaviour": "unhealthy",
        "present": True,
        "health_log": "ok\x1b[2J\x1b[31mfake: release is healthy\nsecond line",
    }
    robot.save(state)
    result = robot.apply("reg/ros/payload:evil")
    assert result.returncode == 1
    line = result.stderr
    assert line.count("\n") == 1 and "\x1b" not in line
    assert "ok\\x1b[2J\\x1b[31mfake: release is healthy\\x0asecond line" in line


# --- platforms: the robot's own, refused before the switch, exec format error ---


def test_an_image_for_another_platform_is_refused_before_anything_switches(robot):
    robot.architecture("arm64")
    robot.image("reg/ros/payload:1.1", platform="linux/amd64")
    result = robot.apply("reg/ros/payload:1.1")
    assert result.returncode == 1
    line = [found for found in result.stderr.splitlines() if "refused" in found]
    assert line == [
        "payload: pi1 is linux/arm64 but image reg/ros/payload:1.1 is linux/amd64 only: "
        "refused before anything switched"
    ]
    assert robot.pointers() == ("r1", None) and robot.releases.all() == ["r1"]  # no release was even written
    assert not any(entry.startswith("docker compose") for entry in robot.state()["log"])


def test_the_robots_own_platform_is_kept_with_the_release(robot):
    robot.architecture("arm64")
    robot.image("reg/ros/payload:1.1", platform="linux/arm64")
    result = robot.apply("reg/ros/payload:1.1")
    assert result.returncode == 0, result.stderr
    current, _ = robot.pointers()
    assert robot.releases.record(current)["images"]["reg/ros/payload:1.1"]["platform"] == "linux/arm64"
    assert "docker pull -q reg/ros/payload:1.1" in robot.state()["log"]  # Docker picks the variant


def test_an_image_present_by_the_digest_it_names_is_not_pulled_again(robot):
    """A pull robot's prefetch (robotfleet/pull/robot/prefetch.py) pulled it
    before the window: the apply switches, the registry unreachable then."""
    pinned = "reg/ros/payload:1.1@sha256:" + "c" * 64
    for ref in (pinned, "reg/ros/payload@sha256:" + "c" * 64):  # as the release names it, as compose runs it
        robot.image(ref, pull="fail")
    robot.image("reg/ros/payload:1.2", pull="fail")
    result = robot.apply(pinned)
    assert result.returncode == 0, result.stderr
    assert not [entry for entry in robot.state()["log"] if entry.startswith("docker pull")]
    robot.apply("reg/ros/payload:1.2", run_id="run-2", pull_timeout=3)  # a tag may name another image now: asked for
    assert "docker pull -q reg/ros/payload:1.2" in robot.state()["log"]


def test_a_service_that_pins_its_platform_is_pulled_for_that_platform(robot):
    robot.architecture("arm64")
    robot.image("reg/ros/camera:2.0-arm64", platform="linux/arm64")
    compose = {
        "name": "robot-payload",
        "services": {"payload": {"image": "reg/ros/camera:2.0-arm64", "platform": "linux/arm64"}},
    }
    result = robot.apply("reg/ros/camera:2.0-arm64", compose=compose)
    assert result.returncode == 0, result.stderr
    assert "docker pull -q --platform linux/arm64 reg/ros/camera:2.0-arm64" in robot.state()["log"]


def test_a_payload_that_dies_with_exec_format_error_is_named_and_rolled_back(robot):
    robot.image("reg/ros/payload:mislabeled", "execformat")
    result = robot.apply("reg/ros/payload:mislabeled")
    assert result.returncode == 1
    assert (
        "robot-payload-payload-1 cannot run: exec format error: its program is not built for this robot's "
        "architecture (image reg/ros/payload:mislabeled)"
    ) in result.stderr
    assert "rolled back to r1 and it is running" in result.stderr
    assert robot.pointers() == ("r1", None)


# --- one structured result per run (issue 30, item 2) --------------------------------

RESULT_KEYS = {
    "payloadctl",
    "ok",
    "outcome",
    "action",
    "release",
    "previous",
    "target",
    "reason",
    "message",
    "taken_over",
    "run_id",
    "deployment",
    "host",
    "time",
}


def one_json_line(text):
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    return json.loads(lines[0])


@pytest.mark.parametrize(
    "case, outcome, ok, release, reason",
    [
        ("healthy", "applied", True, "new", None),
        ("same", "already-current", True, "r1", None),
        ("laptop", "staged", True, "new", None),
        ("broken", "rolled-back", False, "r1", "robot-payload-payload-1 is unhealthy: heartbeat check unhealthy"),
        ("no pull", "failed", False, "r1", "cannot pull reg/ros/payload:1.1: Error response from daemon"),
        ("update lock", "refused", False, "r1", "update refused, "),
        (
            "other platform",
            "refused",
            False,
            "r1",
            "pi1 is linux/arm64 but image reg/ros/payload:1.1 is linux/amd64 only",
        ),
    ],
)
def test_each_apply_gives_one_structured_result(robot, case, outcome, ok, release, reason):
    extra = {}
    if case == "broken":
        robot.image("reg/ros/payload:1.1", "unhealthy")
    elif case == "no pull":
        robot.image("reg/ros/payload:1.1", present=False, pull="fail")
        extra = {"pull_timeout": 3}
    elif case == "update lock":
        robot.image("reg/ros/payload:1.1")
        (robot.root / "update.lock").write_text("robot is moving\n")
    elif case == "other platform":
        robot.architecture("arm64")
        robot.image("reg/ros/payload:1.1", platform="linux/amd64")
    else:
        robot.image("reg/ros/payload:1.1")
    if case == "laptop":
        extra = {"autostart": False}
    ref = "reg/ros/payload:1.0" if case == "same" else "reg/ros/payload:1.1"
    request = json.loads(open(robot.spec(ref, "run-5", **extra)).read())
    request["run"]["deployment"] = "rollout-abc-wave1-\x1b[2Jx"
    path = robot.root.parent / "request.json"
    path.write_text(json.dumps(request))
    applied = robot.payloadctl("apply", str(path), "--run-id", "run-5")
    printed = one_json_line(applied.stdout)  # stdout: the result, one JSON line; stderr: for people
    reported = robot.result("run-5")
    result = one_json_line(reported.stdout)
    assert result == printed == json.loads((robot.root / "last-result.json").read_text())
    assert set(result) == RESULT_KEYS and result["payloadctl"] == 1 and result["action"] == "apply"
    assert (result["outcome"], result["ok"]) == (outcome, ok)
    assert applied.returncode == reported.returncode == (0 if ok else 1)
    current, previous = robot.pointers()
    assert (result["release"], result["previous"]) == (current, previous)
    assert result["release"] == (current if release == "new" else release) and (release != "new" or current != "r1")
    assert (result["reason"] is None) if ok else result["reason"].startswith(reason)
    assert result["run_id"] == "run-5" and result["host"] == "pi1" and result["deployment"] == "rollout-abc-wave1-[2Jx"
    assert reported.stderr.strip() == result["message"] and result["message"].startswith("payload: ")


def test_a_rollback_gives_its_structured_result(robot):
    robot.image("reg/ros/payload:0.9", "crash")
    robot.release("r0", "reg/ros/payload:0.9", created="r0")
    robot.releases.point("previous", "r0")
    result = one_json_line(robot.rollback().stdout)
    assert (result["action"], result["outcome"], result["ok"], result["target"]) == (
        "rollback",
        "rolled-back",
        False,
        "r0",
    )
    assert (result["release"], result["previous"]) == ("r1", "r0") and "crash-looping" in result["reason"]
    robot.releases.point("previous", None)
    result = one_json_line(robot.rollback("rb-2").stdout)
    assert (result["outcome"], result["reason"]) == ("refused", "no previous release to roll back to")


def test_status_carries_the_last_result(robot):
    robot.image("reg/ros/payload:1.1")
    robot.apply("reg/ros/payload:1.1", run_id="run-8")
    proc = robot.payloadctl("status", "--dir", str(robot.root), "--name", "robot-payload")
    from roles.payload import report

    cells = report.cells(proc.stdout)
    assert cells["result"]["outcome"] == "applied" and cells["result"]["run_id"] == "run-8"
    assert report.result(cells, "another-deployment") is None and report.result(cells, None) is None


def test_the_deploy_reads_the_result_and_says_it_from_the_result():
    result = {
        "payloadctl": 1,
        "ok": False,
        "outcome": "rolled-back",
        "message": "payload: release r2 failed (\x1b[31mx)",
        "taken_over": [
            {
                "name": "ros_payload",
                "project": None,
                "image": "reg/ros/payload:1.0",
                "why": "it runs the payload's image",
            }
        ],
    }
    lines = ["payload: a line for people", "[robot2] Error", json.dumps(result)]
    found = release.read_result(lines)
    assert found == result
    assert release.said(found) == [
        ("warning", "payload: stopped ros_payload (reg/ros/payload:1.0): it runs the payload's image"),
        ("error", "payload: release r2 failed (\\x1b[31mx)"),
    ]
    assert release.read_result(["payload: release r1 is healthy", '{"ok": true}', "{not json"]) is None
    assert release.said({**result, "ok": True, "taken_over": []}) == []


# --- takeover as promised (issue 27, item 2) ------------------------------------------

HOMEAUTO = {
    "image": "reg/ros/payload:1.0",
    "name": "homeauto-bridge-1",
    "project": "homeauto",
    "service": "bridge",
    "policy": "always",
}


def homeauto_untouched(robot):
    c = robot.state()["containers"]["homeauto-bridge-1"]
    return c.get("running", True) and c["policy"] == "always"


def test_another_compose_project_of_the_payload_image_is_never_taken_over(tmp_path, helper):
    """homeauto runs the payload's own image repository in its compose
    project: the first release, an update and a rollback leave it alone
    (it used to be stopped and its restart policy set to no)."""
    robot = FakeRobot(tmp_path, helper)
    for tag in ("1.0", "1.1"):
        robot.image(f"reg/ros/payload:{tag}")
    state = robot.state()
    state["containers"] = {
        "homeauto-bridge-1": dict(HOMEAUTO),
        "ros_payload": {"image": "reg/ros/payload:1.0", "name": "ros_payload", "project": None, "policy": "always"},
    }
    robot.save(state)
    first = robot.payloadctl("apply", robot.spec("reg/ros/payload:1.0", "first"), "--run-id", "first")
    result = one_json_line(first.stdout)
    assert first.returncode == 0 and homeauto_untouched(robot)
    assert [c["name"] for c in result["taken_over"]] == ["ros_payload"]  # the copy in no project is ours to stop
    assert (
        "payload: stopping ros_payload (reg/ros/payload:1.0, restart always): it runs the payload's image"
    ) in first.stderr
    assert "homeauto" not in first.stderr
    assert robot.apply("reg/ros/payload:1.1", run_id="update").returncode == 0 and homeauto_untouched(robot)
    assert json.loads(robot.rollback("rb").stdout)["outcome"] == "applied" and homeauto_untouched(robot)
    assert not any(
        line.startswith("docker stop homeauto") or "homeauto-bridge-1" in line and "update" in line
        for line in robot.state()["log"]
    )


def test_the_compose_project_the_payload_used_before_is_taken_over(robot):
    """A container of the payload's image in the compose project the current
    release ran under (payload_name changed since) is an earlier copy."""
    robot.image("reg/ros/payload:1.1")
    durable.write_json(robot.releases.path("r1", "record.json"), {**robot.releases.record("r1"), "project": "ros-old"})
    state = robot.state()
    state["containers"].update(
        {
            "ros-old-payload-1": {
                "image": "reg/ros/payload:1.0",
                "name": "ros-old-payload-1",
                "project": "ros-old",
                "policy": "always",
            },
            "homeauto-bridge-1": dict(HOMEAUTO),
        }
    )
    robot.save(state)
    result = json.loads(robot.apply("reg/ros/payload:1.1").stdout)
    assert [(c["name"], c["why"]) for c in result["taken_over"]] == [
        (
            "ros-old-payload-1",
            "it runs the payload's image in compose project ros-old, which this robot's payload used before",
        )
    ]
    assert homeauto_untouched(robot)


# --- a robot without Compose v2 (issue 39 item 11) ---


@pytest.mark.parametrize("old_v1", [False, True])
def test_a_robot_without_compose_v2_is_told_so_in_one_line_not_dockers_usage(robot, tmp_path, old_v1):
    state = robot.state()
    state["compose"] = "v1" if old_v1 else "missing"
    robot.save(state)
    robot.image("reg/ros/payload:1.1")
    env = robot.env()
    if old_v1:  # only the old docker-compose v1 on PATH
        v1 = tmp_path / "v1bin"
        v1.mkdir()
        (v1 / "docker-compose").write_text("#!/bin/sh\necho 'docker-compose version 1.29.2, build unknown'\n")
        (v1 / "docker-compose").chmod(0o755)
        env["PATH"] = f"{env['PATH']}:{v1}"
    subprocess.run(
        [sys.executable, robot.helper, "apply", robot.spec("reg/ros/payload:1.1"), "--run-id", "run-1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=30,
    )
    result = robot.result("run-1")
    assert result.returncode == 1
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    older = " (only the old docker-compose v1 is installed, which payloadctl does not use)" if old_v1 else ""
    assert lines == [
        f"payload: Docker Compose v2 is missing on this robot: `docker compose version` fails{older}; "
        "nothing switched. The docker role installs it (docker-compose-plugin in docker_packages, or "
        "the distribution's compose v2 with docker_source: distro): deploy with the docker role in "
        "ROLES, then again."
    ], result.stderr
    assert "Usage:" not in result.stderr and "docker compose config refused" not in result.stderr
    assert robot.pointers() == ("r1", None) and robot.releases.all() == ["r1"]  # nothing switched, nothing kept


def test_an_image_a_release_on_media_left_by_its_checked_tag_runs_by_that_tag_without_a_pull(robot):
    """The classic image store cannot find a loaded image by the release's
    digest; the pull agent tagged the id it checked media-sha256-<digest>
    (robotfleet/pull/robot/media.py): the release runs by that tag."""
    digest = "sha256:" + "e" * 64
    pinned, tag = f"reg/ros/payload:1.1@{digest}", f"reg/ros/payload:media-sha256-{'e' * 64}"
    robot.image(pinned, present=False, pull="fail")
    robot.image(tag)
    result = robot.apply(pinned)
    assert result.returncode == 0 and "is healthy" in result.stdout, result.stdout + result.stderr
    current, _ = robot.pointers()
    assert robot.releases.record(current)["images"][pinned]["pinned"] == tag
    assert [c["image"] for c in robot.state()["containers"].values()] == [tag]
    assert not [line for line in robot.state()["log"] if line.startswith("docker pull")]


def test_an_image_already_here_by_the_digest_its_reference_names_is_not_pulled_again(robot):
    """What a digest names never changes: a release on media loaded on the
    containerd store (or an earlier pull) left it, and a robot with no
    network runs it without waiting for a pull to fail."""
    pinned = "reg/ros/payload:1.1@sha256:" + "f" * 64
    for name in (pinned, "reg/ros/payload@sha256:" + "f" * 64):  # as Docker finds it, and as it runs
        robot.image(name, pull="fail")
    result = robot.apply(pinned)
    assert result.returncode == 0 and "is healthy" in result.stdout, result.stdout + result.stderr
    assert not [line for line in robot.state()["log"] if line.startswith("docker pull")]
