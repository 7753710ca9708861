"""The roscore health check's probe, run by the Python of this machine:
it fails while no master answers (the e2e module sees it pass on real ROS:
tests/e2e/test_ros.py)."""

import socket
import subprocess
import sys

from roles.payload import presets


def test_the_probe_fails_while_no_master_answers():
    with socket.socket() as s:
        if s.connect_ex(("127.0.0.1", presets.ROSCORE_PORT)) == 0:
            raise AssertionError(f"something listens on 127.0.0.1:{presets.ROSCORE_PORT}; this test needs it free")
    done = subprocess.run([sys.executable, "-c", presets.ROSCORE_PROBE], capture_output=True, text=True, timeout=30)
    assert done.returncode == 1, done
    assert "Connection refused" in done.stderr
