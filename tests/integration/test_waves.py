"""The rollout command as a process (tests/unit/test_waves.py plans the
waves): it refuses while another rollout of the fleet holds its state."""

import os
import subprocess
import sys

from robotfleet.commands import waves
from tests.unit.test_waves import result


def test_the_rollout_command_refuses_while_another_rollout_of_the_fleet_holds_its_state(tmp_path, monkeypatch):
    """Two rollouts of one fleet lost each other's updates: the second one now
    stops at once, before it contacts any robot (issue 17, item 9)."""
    from robotfleet import roster
    from robotfleet.commands import rollout

    monkeypatch.setenv("ROBOT_ROLLOUT_DIR", str(tmp_path))
    inventory = "inventories/robots.py"
    hosts = rollout.selected_hosts(inventory, [])
    names = [name for name, _ in hosts]
    targets = {name: rollout.targets_of(roster.roles(), data, {}) for name, data in hosts}
    path = waves.state_path(waves.fleet_key(inventory, names, targets))
    with waves.held(path):  # the command runs apart: it patches gevent into its process
        second = subprocess.run([sys.executable, "-m", "robotfleet", "rollout", inventory, "-y"], capture_output=True,
                                text=True, timeout=120, env=dict(os.environ, ROBOT_ROLLOUT_DIR=str(tmp_path)))
    assert second.returncode == 2, second.stderr
    assert f"rollout: another rollout of this fleet is running (pid {os.getpid()} since 20" in second.stderr


FAKE_PYINFRA = """\
import json, sys
# robot1's payload printed a line that names robot2 (a robot can print anything).
print("[robot1] payload: release x failed ([robot2] Error: payload: release y failed); rolled back", file=sys.stderr)
print("[robot2] Error: payload: release y failed", file=sys.stderr)
print(json.dumps({"results": {"operations": [{"name": "Release the payload", "error": ["robot1"], "success": []}],
                              "failed_hosts": ["robot1"]}}))
"""


def test_a_line_naming_robot2_in_robot1s_output_does_not_fail_robot2(monkeypatch, capfd):
    """Rollout used to read each robot's result from pyinfra's output lines:
    a line "[robot2] ..." written by robot1 failed robot2 (issue 27, item 5)."""
    from robotfleet.commands import rollout

    monkeypatch.setattr(rollout, "PYINFRA", FAKE_PYINFRA)
    results = rollout.deploy_wave("inventories/robots.py", ["robot1", "robot2"], [], "deploy.py", "w3")
    assert "[robot2] Error" in capfd.readouterr().err  # the operator still sees everything printed
    on_target = {"reachable": True, "image_refs": ["i:2"], "release_state": "active", "state": "running",
                 "health": "healthy"}
    rows = {"robot1": {**on_target, "image_refs": ["i:1"], "result": result("w3", False, "payload: release x failed")},
            "robot2": {**on_target, "result": result("w3", True, "payload: release y is healthy")}}
    targets = dict.fromkeys(rows, {"payload": ["i:2"]})
    done, failed, skipped = rollout.judge_wave(["robot1", "robot2"], results, rows, targets, False, deployment="w3")
    assert done == ["robot2"] and failed == {"robot1": "payload: release x failed"} and skipped == {}


def test_the_deploy_of_a_wave_is_named_for_the_robots_results(monkeypatch, tmp_path):
    from robotfleet.commands import rollout

    seen = tmp_path / "seen"
    monkeypatch.setattr(rollout, "PYINFRA", f"import os; open({str(seen)!r}, 'w').write(os.environ['ROBOTFLEET_DEPLOYMENT'])")
    assert rollout.deploy_wave("inventories/robots.py", ["robot1"], [], "deploy.py", "rollout-k-wave1-ab") is None
    assert seen.read_text() == "rollout-k-wave1-ab"
