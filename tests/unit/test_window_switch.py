"""A pull release prepared before its maintenance window and switched to
in it (robotfleet/pull/robot/window_switch.py): what the planning run reads of
pyinfra's dry plan, and the payload's release written for the switch
instead of applied."""

import json
import shutil
import tempfile
from pathlib import Path

import pytest

from robotfleet.pull.robot.window_switch import plan_changes
from roles.payload import release
from roles.payload.window_switch import SWITCH
from tests.unit.harness import ROBOT, converged, merged, plan

REG = "reg.example.com"
PAYLOAD = f"{REG}/ros/payload:1.1"
A, B = ("sha256:" + x * 64 for x in "ab")


def dry(*ops) -> str:
    return "--> some log line\n" + json.dumps({"plan": list(ops), "results": None})


def op(name, changed=(), conditional=()):
    return {"name": name, "hosts_with_change": list(changed), "hosts_with_conditional_change": list(conditional)}


def test_the_plan_names_only_the_operations_that_would_change_the_host():
    assert plan_changes(dry(op("Payload | Release"), op("systemd daemon-reload", conditional=["@local"]))) == []
    assert plan_changes(dry(op("Docker | Write daemon.json", ["@local"]), op("Payload | Release"))) == [
        "Docker | Write daemon.json"
    ]


@pytest.mark.parametrize("stdout", ["", "pyinfra: error", '{"results": null}', '{"plan": 3}', "{not json"])
def test_output_without_a_plan_is_no_plan(stdout):
    assert plan_changes(stdout) is None


def test_only_the_planning_run_on_the_robot_itself_writes_its_release():
    data = merged("robots", {**ROBOT, "payload_switch_request": "/var/lib/robot-pull/runs/x/payload.switch.json"})
    assert release.prepares(data, False, "@local", planning=True)
    assert not release.prepares(data, True, "@local", planning=True)  # a unit change is applied whole, in the window
    assert not release.prepares(data, False, "robot1", planning=True)  # a push deploy: the file would be the operator's
    assert not release.prepares(data, False, "@local", planning=False)  # a run that executes (-y) applies
    assert not release.prepares(merged("robots", ROBOT), False, "@local", planning=True)
    assert SWITCH.setting == "payload_switch_request"


@pytest.fixture
def private_dir():
    """A directory only its owner writes (the setting refuses one under /tmp, as the agent's is)."""
    path = Path(tempfile.mkdtemp(dir=Path.home()))
    yield path
    shutil.rmtree(path)


def test_the_planning_run_writes_the_new_release_for_the_switch_and_plans_no_change(private_dir, monkeypatch):
    monkeypatch.setattr(release, "WRITES_HERE", ("@fake/r1",))  # the harness's hosts stand for @local
    data = {**ROBOT, "payload_image": PAYLOAD, "payload_image_pins": {PAYLOAD: A}}
    snap = converged("robots", data, "debian-13")
    request = private_dir / "payload.switch.json"
    new = {**data, "payload_image_pins": {PAYLOAD: B}, "payload_switch_request": str(request)}
    planned = plan({"r1": ("robots", new, snap)}, run=False)  # what --dry does
    assert planned.changes["r1"] == []  # nothing would change: the release is written for the switch
    written = json.loads(request.read_text())
    assert written["spec"]["compose"]["services"]["payload"]["image"] == f"{PAYLOAD}@{B}"
    assert oct(request.stat().st_mode & 0o777) == "0o600"
    # the same release without the setting would change the robot, and is applied
    without = {**data, "payload_image_pins": {PAYLOAD: B}}
    assert planned.changes["r1"] != plan({"r1": ("robots", without, snap)}, run=False).changes["r1"]
    commands = plan({"r1": ("robots", without, snap)})["r1"]
    assert len(commands) == 1 and "payloadctl apply" in commands[0]
    # with the setting, a run that executes applies it all the same (the window's converge: -y)
    request.unlink()
    commands = plan({"r1": ("robots", new, snap)})["r1"]
    assert len(commands) == 1 and "payloadctl apply" in commands[0]


def test_the_switch_and_its_result_as_payloadctl_says_them():
    data = merged("robots", ROBOT)
    argv = SWITCH.switch(data, "20261128T000000Z-hab", "pull-r1-7-abc")
    assert argv[2:] == [
        "switch",
        "--dir",
        "/var/lib/robot-payload",
        "--release",
        "20261128T000000Z-hab",
        "--by",
        "pull agent",
        "--deployment",
        "pull-r1-7-abc",
    ]
    assert SWITCH.prepare(data, "/x/payload.switch.json")[2:] == ["prepare", "/x/payload.switch.json"]
    line = {"payloadctl": 1, "ok": True, "outcome": "prepared", "target": "r2", "message": "payload: r2 is prepared"}
    said = SWITCH.read("payload: r2 is prepared\n" + json.dumps(line) + "\n")
    assert said == {"ok": True, "outcome": "prepared", "target": "r2", "message": "payload: r2 is prepared"}
    assert SWITCH.read("Traceback ...\n") is None
