"""The rollout command as a process (tests/unit/test_waves.py plans the
waves): one rollout per fleet whatever the flags; each robot's result from
structured data, never from output lines."""

import os
import subprocess
import sys

import pytest

from tests.unit.samples import result

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
    from robotfleet.commands import rollout, rollout_judge

    monkeypatch.setattr(rollout, "PYINFRA", FAKE_PYINFRA)
    results = rollout.deploy_wave("inventories/robots.py", ["robot1", "robot2"], [], "deploy.py", "w3")
    assert "[robot2] Error" in capfd.readouterr().err  # the operator still sees everything printed
    on_target = {
        "reachable": True,
        "image_refs": ["i:2"],
        "release_state": "active",
        "state": "running",
        "health": "healthy",
    }
    rows = {
        "robot1": {**on_target, "image_refs": ["i:1"], "result": result("w3", False, "payload: release x failed")},
        "robot2": {**on_target, "result": result("w3", True, "payload: release y is healthy")},
    }
    targets = dict.fromkeys(rows, {"payload": ["i:2"]})
    done, failed, skipped = rollout_judge.judge_wave(
        ["robot1", "robot2"], results, rows, targets, False, deployment="w3"
    )
    assert done == ["robot2"] and failed == {"robot1": "payload: release x failed"} and skipped == {}


def test_the_deploy_of_a_wave_is_named_for_the_robots_results(monkeypatch, tmp_path):
    from robotfleet.commands import rollout

    seen = tmp_path / "seen"
    monkeypatch.setattr(
        rollout, "PYINFRA", f"import os; open({str(seen)!r}, 'w').write(os.environ['ROBOTFLEET_DEPLOYMENT'])"
    )
    assert rollout.deploy_wave("inventories/robots.py", ["robot1"], [], "deploy.py", "rollout-k-wave1-ab") is None
    assert seen.read_text() == "rollout-k-wave1-ab"


@pytest.mark.parametrize(
    "flags",
    [["--limit", "robot2"], ["--data", "payload_image=reg.example.com/p:2"], ["--canary", "2", "--max-failed", "1"]],
)
def test_one_rollout_lock_per_fleet_whatever_the_flags(tmp_path, flags):
    """Two rollouts of one fleet lost each other's updates (issue 17, item 9);
    a second one with another --limit or --data ran beside the first (its
    lock was its command line's, issue 27, item 8): it now stops at once,
    before it contacts any robot.  The first one runs for real, waiting on
    robots that never answer."""
    import glob
    import time

    from robotfleet.fleet import yaml12
    from tests.integration import sshserver

    silent = [sshserver.Unanswered() for _ in range(2)]
    fleet = tmp_path / "fleet.yaml"
    fleet.write_text(
        yaml12.dump(
            {
                "all": {"vars": {"payload_image": "reg.example.com/p:1", "ssh_connect_timeout": 20}},
                "robots": {
                    "hosts": {
                        f"robot{i + 1}": {"address": "127.0.0.1", "ssh_port": s.port} for i, s in enumerate(silent)
                    }
                },
            }
        )
    )
    env = dict(os.environ, ROBOT_ROLLOUT_DIR=str(tmp_path / "states"), ROBOT_FLEET=str(fleet))
    command = [sys.executable, "-m", "robotfleet", "rollout", "inventories/robots.py", "-y"]
    first = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 30
        while not glob.glob(str(tmp_path / "states" / "*.lock")) and time.monotonic() < deadline:
            time.sleep(0.1)
        second = subprocess.run(command + flags, capture_output=True, text=True, timeout=120, env=env)
    finally:
        first.kill()
        first.wait()
        for server in silent:
            server.close()
    assert second.returncode == 2, second.stderr
    assert second.stderr.splitlines()[-1].startswith(
        f"rollout: another rollout of this fleet is running (pid {first.pid} since 20"
    )
