"""`payloadctl prepare` and `payloadctl switch`: an apply split at the
prepared state, for a pull robot's maintenance window (the prepare before
it, the switch in it), against the fake docker and systemctl of
tests/integration/payloadrobot.py."""

import json
import os

from tests.integration.payloadrobot import one_json_line


def prepare(robot, ref, run_id="prep-1", **extra):
    done = robot.payloadctl("prepare", robot.spec(ref, run_id, **extra), "--run-id", run_id)
    return one_json_line(done.stdout), done


def switch(robot, rid, run_id="sw-1", deployment="pull-pi1-7-abc"):
    done = robot.payloadctl(
        "switch", "--dir", str(robot.root), "--release", rid, "--run-id", run_id, "--deployment", deployment
    )
    return one_json_line(done.stdout), done


def test_prepare_writes_the_release_and_touches_nothing_that_runs(robot):
    robot.image("reg/ros/payload:1.1")
    result, done = prepare(robot, "reg/ros/payload:1.1")
    assert done.returncode == 0 and result["outcome"] == "prepared" and result["ok"]
    rid = result["target"]
    assert robot.releases.record(rid)["state"] == "prepared"
    assert os.path.isfile(robot.releases.path(rid, "compose.yaml")) and robot.pointers() == ("r1", None)
    assert "started" not in robot.state()  # nothing started, nothing stopped
    assert robot.state()["containers"]["robot-payload-payload-1"]["image"] == "reg/ros/payload:1.0"


def test_a_second_prepare_of_the_same_spec_names_the_same_release(robot):
    robot.image("reg/ros/payload:1.1")
    first, _ = prepare(robot, "reg/ros/payload:1.1")
    again, _ = prepare(robot, "reg/ros/payload:1.1", run_id="prep-2")
    assert again["outcome"] == "prepared" and again["target"] == first["target"]
    assert len(robot.releases.ids()) == 2  # r1 and the one prepared


def test_prepare_of_what_runs_is_already_current(robot):
    result, _ = prepare(robot, "reg/ros/payload:1.0")
    assert result["outcome"] == "already-current" and result["target"] == "r1"


def test_prepare_refuses_a_release_compose_refuses_and_leaves_nothing(robot):
    robot.image("reg/ros/payload:1.1")
    state = robot.state()
    state["compose_refuses"] = "services.payload Additional property bad is not allowed"
    robot.save(state)
    result, done = prepare(robot, "reg/ros/payload:1.1")
    assert done.returncode == 1 and result["outcome"] == "refused"
    assert "Additional property bad" in result["reason"] and robot.releases.ids() == ["r1"]


def test_switch_runs_the_prepared_release_health_gated_and_names_the_deployment(robot):
    robot.image("reg/ros/payload:1.1")
    rid = prepare(robot, "reg/ros/payload:1.1")[0]["target"]
    result, done = switch(robot, rid)
    assert done.returncode == 0 and result["outcome"] == "applied" and result["action"] == "switch"
    assert result["deployment"] == "pull-pi1-7-abc" and result["target"] == rid
    assert robot.pointers() == (rid, "r1") and robot.releases.record(rid)["state"] == "active"
    assert robot.state()["started"] == ["reg/ros/payload:1.1"]
    last = json.loads((robot.root / "last-result.json").read_text())
    assert last["run_id"] == "sw-1" and last["outcome"] == "applied"


def test_a_prepared_release_that_fails_its_gate_rolls_back_as_an_apply_does(robot):
    robot.image("reg/ros/payload:bad", "crash")
    rid = prepare(robot, "reg/ros/payload:bad")[0]["target"]
    result, done = switch(robot, rid)
    assert done.returncode == 1 and result["outcome"] == "rolled-back"
    assert robot.pointers() == ("r1", None) and robot.releases.record(rid)["state"] == "failed"
    assert robot.state()["started"][-1] == "reg/ros/payload:1.0"


def test_switch_refuses_a_release_that_is_not_prepared_and_changes_nothing(robot):
    for rid in ("r1", "no-such", "../payload"):
        result, done = switch(robot, rid)
        assert done.returncode == 1 and result["outcome"] == "refused", rid
        assert "not prepared: nothing switched" in result["reason"], rid
    assert robot.pointers() == ("r1", None) and "started" not in robot.state()


def test_switch_honours_the_update_lock_as_an_apply_does(robot):
    robot.image("reg/ros/payload:1.1")
    rid = prepare(robot, "reg/ros/payload:1.1")[0]["target"]
    (robot.root / "update.lock").write_text("field test until 17:00\n")
    result, done = switch(robot, rid)
    assert done.returncode == 1 and result["outcome"] == "refused" and "update.lock is held" in result["reason"]
    assert robot.releases.record(rid)["state"] == "prepared" and robot.pointers() == ("r1", None)


def test_switch_takes_a_release_s_name_only_never_a_path_to_a_prepared_record_elsewhere(robot):
    robot.image("reg/ros/payload:1.1")
    robot.release("../elsewhere", "reg/ros/payload:1.1", state="prepared")  # a record beside releases/
    result, done = switch(robot, "../elsewhere")
    assert done.returncode == 1 and result["outcome"] == "refused" and "missing, not prepared" in result["reason"]
    assert robot.pointers() == ("r1", None) and "started" not in robot.state()
