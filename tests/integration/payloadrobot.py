"""The stand-in robot of payloadctl's integration tests: the release store
written straight to disk, fake `docker` and `systemctl` first on PATH
(tests/integration/fakebin) answering from a JSON state file, and the real
helper run as a process (tests/integration/test_payloadctl*.py)."""

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

from roles.payload.payloadctl import durable, health, lifecycle
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


def switching(robot, rid, ref, kind, came_from, previous_before, **extra):
    robot.release(
        rid,
        ref,
        state="switching",
        created=rid,
        switch={"kind": kind, "from": came_from, "previous_before": previous_before, **extra},
    )


def wait_until(predicate, what, seconds=10):
    import time

    deadline = time.time() + seconds
    while time.time() < deadline:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def one_json_line(text):
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    return json.loads(lines[0])
