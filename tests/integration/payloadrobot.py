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

from roles.payload.payloadctl import durable, lifecycle
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
    def __init__(self, tmp_path, helper, python=sys.executable):
        self.root = tmp_path / "payload"
        self.root.mkdir()
        self.helper, self.python = helper, str(python)  # python: the robot's python3
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
            [self.python, self.helper, *args], env=self.env(), capture_output=True, text=True, timeout=timeout
        )

    def env(self, **more):
        return dict(
            os.environ,
            PATH=f"{FAKEBIN}:{os.environ['PATH']}",
            FAKE_STATE=str(self.state_path),
            FAKE_HELPER=self.helper,
            FAKE_PYTHON=self.python,
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
