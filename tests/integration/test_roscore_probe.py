"""The roscore health check's probe, run by the Python of this machine:
it fails while no master answers (the e2e module sees it pass on real ROS:
tests/e2e/test_ros.py)."""

import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from roles.payload import presets


def test_the_probe_fails_while_no_master_answers():
    with socket.socket() as s:
        if s.connect_ex(("127.0.0.1", presets.ROSCORE_PORT)) == 0:
            raise AssertionError(f"something listens on 127.0.0.1:{presets.ROSCORE_PORT}; this test needs it free")
    done = subprocess.run([sys.executable, "-c", presets.ROSCORE_PROBE], capture_output=True, text=True, timeout=30)
    assert done.returncode == 1, done
    assert "Connection refused" in done.stderr


@pytest.mark.parametrize("engine, kept", [("24.0.7", False), ("26.1.5", True)])
def test_a_release_on_an_engine_older_than_25_is_written_without_start_interval(robot, engine, kept):
    """Compose refuses start_interval on Docker < 25 and starts nothing: payloadctl asks the engine."""
    state = robot.state()
    state["engine"] = engine
    robot.save(state)
    robot.image("reg/ros/payload:1.1")
    check = {**presets.ROSCORE_HEALTHCHECK, "test": ["CMD", "true"]}
    compose = {"name": "robot-payload", "services": {"payload": {"image": "reg/ros/payload:1.1", "healthcheck": check}}}
    assert robot.apply("reg/ros/payload:1.1", compose=compose).returncode == 0
    written = robot.releases.path(robot.pointers()[0], "compose.yaml")
    healthcheck = json.loads(Path(written).read_text().split("\n", 1)[1])["services"]["payload"]["healthcheck"]
    assert ("start_interval" in healthcheck) == kept and healthcheck["interval"] == "10s"
