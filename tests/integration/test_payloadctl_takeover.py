"""payloadctl (tests/integration/payloadrobot.py) taking over an earlier copy
of the payload, and never another compose project of the same image."""

import json

from roles.payload.payloadctl import durable
from tests.integration.payloadrobot import FakeRobot, one_json_line


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
