"""The rollout command as a process (tests/unit/test_waves.py plans the
waves): it refuses while another rollout of the fleet holds its state."""

import os
import subprocess
import sys

from robotfleet.commands import waves


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
