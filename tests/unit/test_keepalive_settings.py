"""The keepalive bound (issue 51, item 2) is one pair of defaults wherever it
is read: the engine's settings (robotfleet/fleet/connection.py), the SSH
connector's data (robotfleet/connect.py), a pull robot's agent config and
its ssh (robotfleet/pull/protocol/agent_files.py, robotfleet/pull/robot/ssh_options.py)."""

from __future__ import annotations

from robotfleet import connect, keepalive
from robotfleet.fleet import connection
from robotfleet.pull.protocol import agent_files
from robotfleet.pull.robot import ssh_options


def test_every_reader_of_the_keepalives_has_the_same_defaults():
    settings = {s.name: s.default for s in connection.SETTINGS}
    pair = (settings["ssh_keepalive_interval"], settings["ssh_keepalive_count_max"])
    meta = connect.FleetConnector.data_meta
    assert (meta["ssh_keepalive_interval"].default, meta["ssh_keepalive_count_max"].default) == pair
    assert (agent_files.default("keepalive_interval"), agent_files.default("keepalive_count_max")) == pair
    assert ssh_options.KEEPALIVE == pair
    assert ssh_options.silence(pair) == 60  # the default gives up on a link silent for a minute


def test_ssh_gets_the_same_bound():
    assert keepalive.openssh_options(2, 3) == ["-o", "ServerAliveInterval=2", "-o", "ServerAliveCountMax=3"]
    command = ssh_options.ssh_command(["/k"], "/kh", "/log", 300, (2, 3))
    assert "ServerAliveInterval=2 -o ServerAliveCountMax=3" in command
