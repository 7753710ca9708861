"""The integration tests' own SSH listener (tests/integration/sshserver.py):
once closed, its port answers no one.  A listener whose thread still waited
in accept() kept listening in the kernel, and under load a later test's
server came to share its port: the robot's ssh met the earlier server's
host key."""

from __future__ import annotations

import socket
import time

import pytest

from tests.integration import sshserver


def test_a_closed_listener_no_longer_listens():
    listener = sshserver.Listener()
    port = listener.port
    time.sleep(0.2)  # its thread now waits in accept()
    listener.close()
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", port), timeout=2).close()
