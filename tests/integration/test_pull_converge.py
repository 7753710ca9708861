"""A pull robot's converge run in the release's code (robotfleet/pull/robot/converge.py)
and the inventory it runs pyinfra with (inventories/pull.py)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import SimpleNamespace

from robotfleet.pull.protocol import robot_data
from robotfleet.pull.robot import converge
from robotfleet.role import RolloutPart
from tests.fixtures import pyinfra

ROOT = Path(__file__).resolve().parents[2]
FLEET = """\
all:
  vars: {payload_image: "reg.example.com/ros/payload:1.0"}
robots:
  vars: {pull_enabled: true, pull_remote: "https://git.lan/fleet.git"}
  hosts:
    robot1: {address: 10.0.0.1, ssh_user: ops, ros_domain_id: 9}
laptops:
  hosts:
    laptop1: {pull_enabled: true, pull_remote: "https://git.lan/fleet.git", x11_user: alice, docker_users: [alice]}
"""


def inventory(tmp_path, robot: str, run: dict | None = None) -> tuple[int, str, dict | None]:
    fleet = tmp_path / "fleet.yaml"
    fleet.write_text(FLEET)
    env = dict(os.environ, ROBOT_FLEET=str(fleet), ROBOT_FLEET_HOST=robot)
    if run is not None:
        (tmp_path / "run.json").write_text(json.dumps(run))
        env["ROBOT_PULL_DATA"] = str(tmp_path / "run.json")
    done = pyinfra("inventories/pull.py", "debug-inventory", env=env)
    out = done.stdout + done.stderr
    data = json.JSONDecoder().raw_decode(out.split("--> Data:", 1)[1].strip())[0] if "--> Data:" in out else None
    groups = next((line for line in out.splitlines() if "--> Groups:" in line), "")
    return done.returncode, out + groups, data


def test_the_pull_inventory_is_the_robot_on_local_with_the_run_s_data(tmp_path):
    (tmp_path / "token").write_text("abc123\n")
    code, out, data = inventory(
        tmp_path,
        "robot1",
        {
            "data": {
                "payload_image_pins": {"reg.example.com/ros/payload:1.0": "sha256:" + "a" * 64},
                "pull_agent_run": {"robot": "robot1", "version": 3},
            },
            "tokens": {"payload_lock_token": str(tmp_path / "token")},
        },
    )
    assert code == 0, out
    assert "[@local]" in out and "robots" in out
    assert data["ros_domain_id"] == 9 and data["payload_lock_token"] == "abc123"
    assert data["pull_agent_run"] == {"robot": "robot1", "version": 3}
    assert "ssh_user" not in data and "ssh_hostname" not in data  # @local: no SSH settings
    assert data["_sudo"] is (os.geteuid() != 0)


def test_a_robot_in_another_group_and_one_the_release_is_not_for(tmp_path):
    code, out, data = inventory(tmp_path, "laptop1")
    assert code == 0 and data["x11_user"] == "alice" and "laptops" in out
    code, out, _ = inventory(tmp_path, "robot9")
    assert code == 2 and "no host named 'robot9'; the release is not for this robot" in out


def role(name, result=None, missing=None, runs=True):
    return SimpleNamespace(
        name=name,
        runs_on=lambda data: runs,
        rollout=RolloutPart(target=lambda data: ["img"], missing=lambda row, target: missing, result=result),
    )


def test_the_run_s_outcome_is_read_from_the_roles_parts():
    row = {"result": {"deployment": "pull-r1-3-ab", "outcome": "rolled-back"}, "other": {"deployment": "old"}}
    roles = [
        role("payload", result=lambda row, d: (False, "release x failed; rolled back to y")),
        role("docker", missing="docker is not running"),
        role("gpu", runs=False, missing="no gpu"),
    ]
    assert converge.results(roles, {}, row, "pull-r1-3-ab") == [
        {"role": "payload", "ok": False, "why": "release x failed; rolled back to y", "outcome": "rolled-back"}
    ]
    assert converge.missing(roles, {}, row) == [{"role": "docker", "why": "docker is not running"}]


def test_pyinfra_s_lines_that_say_why():
    stderr = (
        "--> Starting operation: X\n    [@local] Success\n    [@local] Error: payload: refused\n"
        "--> pyinfra error: No hosts remaining!\n"
    )
    assert converge.errors_of(stderr) == ["[@local] Error: payload: refused", "--> pyinfra error: No hosts remaining!"]
    assert converge.errors_of("only this\n") == ["only this"]


def test_without_a_fleet_file_a_robot_s_defaults():
    from robotfleet import deploy_roles

    data = robot_data.host_data("robot1", None, deploy_roles.registry())
    assert data.payload_dir == "/var/lib/robot-payload" and data.payload_autostart is True


def test_what_the_roles_status_watches_and_how_a_change_shows(tmp_path):
    """The agent reads the roles' status again only when one of these changed
    (or at its heartbeat): the payload's directory and unit invocation, dockerd."""
    from robotfleet import deploy_roles
    from robotfleet.pull.protocol import path_signatures

    data = robot_data.host_data("robot1", None, deploy_roles.registry())
    assert set(converge.watch(deploy_roles.roles(), data)) == {
        "/var/lib/robot-payload",
        "/run/systemd/units/invocation:robot-payload.service",
        "/usr/bin/dockerd",
    }
    directory, link = tmp_path / "payload", tmp_path / "current"
    directory.mkdir()
    link.symlink_to("releases/1")
    paths = [str(directory), str(link), str(tmp_path / "absent")]
    before = path_signatures.watched(paths)
    assert before[str(tmp_path / "absent")] == "-" and before[str(link)].endswith(":releases/1")
    assert path_signatures.watched(paths) == before
    (directory / ".last-result.json.tmp").write_text("{}")
    os.replace(directory / ".last-result.json.tmp", directory / "last-result.json")
    link.unlink()
    link.symlink_to("releases/2")
    after = path_signatures.watched(paths)
    assert after[str(directory)] != before[str(directory)] and after[str(link)].endswith(":releases/2")
