"""The payload's secret files (issue 50, item 3): a file on the operator's
machine sent to the robot 0600 over stdin, mounted in every service as a
compose secret, never in the fleet file, the compose file, a command line or
--diff; a changed one makes the containers anew; a pull robot's own run
sends nothing and needs the file there."""

from __future__ import annotations

import json
import logging

import pytest

from robotfleet.host.fixtures import file_state
from robotfleet.host.snapshot import FileState
from robotfleet.pull.protocol.agent_files import AGENT_RUN
from tests.unit.harness import ROBOT, converged, everything_sent, find, fleet_problems, plan, written_files

SECRET = "db-pa55-Ω\n"
ON_ROBOT = "/var/lib/robot-payload/secrets/db"


@pytest.fixture
def secret(tmp_path):
    path = tmp_path / "db.pw"
    path.write_text(SECRET)
    return {**ROBOT, "payload_secret_files": {"db": str(path)}}


def spec_sent(commands) -> dict:
    (apply,) = find(commands, "payloadctl apply")
    return json.loads(apply.stdin)["spec"]


def test_a_secret_file_reaches_the_robot_0600_by_stdin_and_every_service_mounts_it(secret):
    commands = plan({"r1": ("robots", secret, converged("robots", ROBOT, "debian-13"))})["r1"]
    assert written_files(commands)[ON_ROBOT] == SECRET
    (write,) = [c for c in commands if f"dest={ON_ROBOT}\n" in c]
    assert 'chmod 600 "$tmp"' in write and 'chown root:root "$tmp"' in write
    assert find(commands, "install -d -m 700 -o root -g root /var/lib/robot-payload/secrets")
    assert all("pa55" not in c for c in commands)  # on no command line; its content only in the write's stdin
    compose = spec_sent(commands)["compose"]
    assert compose["secrets"] == {"db": {"file": ON_ROBOT}}
    assert compose["services"]["payload"]["secrets"] == ["db"]
    assert "pa55" not in json.dumps(compose)  # the compose file names the path only
    assert "--restart" in find(commands, "payloadctl apply")[0]  # made anew: compose binds the file at creation


def test_a_robot_holding_the_secret_changes_nothing_and_a_changed_one_makes_the_containers_anew(secret, tmp_path):
    snap = converged("robots", secret, "debian-13")
    assert plan({"r1": ("robots", secret, snap)})["r1"] == []
    (tmp_path / "db.pw").write_text("rotated\n")
    commands = plan({"r1": ("robots", secret, snap)})["r1"]
    assert written_files(commands)[ON_ROBOT] == "rotated\n"
    assert "--restart" in find(commands, "payloadctl apply")[0]
    snap.files[ON_ROBOT] = FileState("file", snap.files[ON_ROBOT].sha256, "644", "root", "root")
    (tmp_path / "db.pw").write_text(SECRET)
    commands = plan({"r1": ("robots", secret, snap)})["r1"]  # a chmod reaches the containers' bind as it is
    assert [c for c in commands if "chmod 600" in c] and not find(commands, "payloadctl apply")


def test_diff_says_a_secret_file_changes_and_never_what_it_holds(secret, caplog):
    caplog.set_level(logging.INFO, logger="pyinfra")
    snap = converged("robots", secret, "debian-13")
    snap.files[ON_ROBOT] = file_state("old-pa55\n", "600")
    plan({"r1": ("robots", secret, snap)}, run=False, diff=True, contents={"r1": {ON_ROBOT: "old-pa55\n"}})
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert f"Will modify {ON_ROBOT} (a secret: its content is not shown)" in text.replace("\x1b[1m", "").replace(
        "\x1b[0m", ""
    )
    assert "pa55" not in text


def test_a_secret_file_that_cannot_be_read_fails_that_robot_in_one_line(secret, tmp_path):
    (tmp_path / "db.pw").unlink()
    result = plan({"r1": ("robots", secret, converged("robots", ROBOT, "debian-13"))})
    assert result.failed == {"r1"}
    (failing,) = find(result["r1"], "exit 1")
    assert f"payload: payload_secret_files.db: cannot read {tmp_path}/db.pw: No such file or directory" in failing
    assert not find(result["r1"], "payloadctl apply")


def test_a_pull_robot_s_own_run_sends_no_secret_and_needs_the_file_there(secret):
    """The agent applies a release on the robot (@local): the operator's path
    means nothing there; the push deploy that installed the agent placed the file."""
    agent = {**secret, AGENT_RUN: {"robot": "r1", "version": 3, "release": "3-x"}}
    snap = converged("robots", secret, "debian-13")
    assert plan({"r1": ("robots", agent, snap)})["r1"] == []  # the same compose project: nothing to release
    del snap.files[ON_ROBOT]
    result = plan({"r1": ("robots", agent, snap)})
    assert result.failed == {"r1"} and not written_files(result["r1"])
    assert (
        f"payload: payload_secret_files.db: {ON_ROBOT} is missing on this robot or not a file of root with mode "
        "0600; a release carries no secret: the push deploy that installs the pull agent puts it there, or the "
        "image the robot boots from"
    ) in everything_sent(result["r1"])


def test_secret_files_stay_outside_the_checkout_and_services_name_only_declared_ones(tmp_path):
    from tests.fixtures import ROOT

    doc = {
        "robots": {
            "vars": {"payload_image": None, "payload_secret_files": {"db": str(ROOT / "db.pw"), "api.env": "~/api"}},
            "hosts": {
                "robot1": {
                    "payload_services": {
                        "slam": {
                            "image": "reg.example.com/ros/slam:1.0",
                            "secrets": ["db", {"source": "tls"}],
                            "env_file": ["/var/lib/robot-payload/secrets/api.env"],
                        }
                    }
                }
            },
        }
    }
    assert fleet_problems(doc) == [
        f"robots.yaml: robot1.payload_secret_files.db: {str(ROOT / 'db.pw')!r} is inside the checkout {ROOT}; "
        "keep secrets outside the repository (e.g. ~/.config/robotfleet/)",
        "robots.yaml: robot1.payload_services.slam.secrets[1]: no secret 'tls' in payload_secret_files "
        "(the robot has only those)",
    ]
