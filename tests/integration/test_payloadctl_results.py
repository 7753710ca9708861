"""payloadctl's structured results (tests/integration/payloadrobot.py): one
JSON line per apply and rollback, what the deploy reads and says from them,
text the robot controls as one printable line, a robot without compose v2."""

import json
import subprocess
import sys

import pytest

from roles.payload import release
from tests.integration.payloadrobot import one_json_line


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


def test_status_carries_the_releases_kept_newest_first(robot):
    """The page of status --html shows a robot's release history from them (roles/payload/report.py's history)."""
    from roles.payload import report

    for tag in ("1.1", "broken"):
        robot.image(f"reg/ros/payload:{tag}", behaviour="unhealthy" if tag == "broken" else "healthy")
        robot.apply(f"reg/ros/payload:{tag}")
    proc = robot.payloadctl("status", "--dir", str(robot.root), "--name", "robot-payload")
    cells = report.cells(proc.stdout)
    kept = cells["releases"]
    assert [r["id"] for r in kept] == list(reversed(robot.releases.all()))  # newest first, as the store orders them
    [failed] = [r for r in kept if r["state"] == "failed"]
    assert "unhealthy" in failed["reason"] and failed["id"] not in (cells["release"], cells["previous"])
    said = dict((text.split(" ")[0], what) for what, text in report.history(cells) if what != "last run")
    assert said == {cells["release"]: "current", cells["previous"]: "previous", failed["id"]: "failed"}
    assert report.history(cells)[-1][0] == "last run"  # the broken release's run was rolled back


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
