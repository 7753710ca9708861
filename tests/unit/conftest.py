"""The unit layer is pure: a test here that starts a process or opens a
socket fails and names where it belongs (tests/integration/)."""

import os
import socket
import subprocess

import pytest


def _refused(what: str):
    def refused(*args, **kwargs):
        raise AssertionError(f"a unit test {what}: it belongs in tests/integration/")

    return refused


@pytest.fixture(autouse=True)
def _no_process_or_socket(monkeypatch):
    monkeypatch.setattr(subprocess.Popen, "_execute_child", _refused("starts a process"))
    for name in ("system", "fork", "forkpty", "posix_spawn", "posix_spawnp"):
        if hasattr(os, name):
            monkeypatch.setattr(os, name, _refused("starts a process"))
    for name in ("bind", "connect", "connect_ex"):
        monkeypatch.setattr(socket.socket, name, _refused("opens a socket"))
