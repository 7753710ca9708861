"""A pull robot's fetches and report pushes against a fleet remote that
accepts and then stalls (issue 51, item 2): given up after the silence the
host's SSH keepalives allow (``ssh_keepalive_interval``,
``ssh_keepalive_count_max``, carried in the agent's config), not after the
whole ``pull_fetch_timeout``: over SSH by ssh's ServerAliveInterval and
ServerAliveCountMax, over HTTPS by curl's low-speed limit.  Real servers on
127.0.0.1, a frozen link in front of the SSH one (tests/lab/linkproxy.py).
Before: ssh kept its own 15 s x 4 and curl waited the whole timeout."""

from __future__ import annotations

import subprocess
import threading
import time

import pytest

from robotfleet import keepalive
from robotfleet.pull.protocol import agent_files
from robotfleet.pull.robot import transport
from tests.integration import httpsgit, sshserver
from tests.integration.reportremotes import report
from tests.lab.linkproxy import Link

KEEPALIVE = (1, 1)  # given up after 2 s without an answer
TIMEOUT = 60  # pull_fetch_timeout: far beyond


def test_the_agent_s_config_carries_the_host_s_keepalives():
    config = agent_files.for_host({"pull_remote": "ssh://git@git.lan/fleet", "ssh_keepalive_interval": 5}, "robot1")
    assert (config.keepalive_interval, config.keepalive_count_max) == (5, 3)
    assert agent_files.read_config(config.to_json()) == config
    default = agent_files.for_host({"pull_remote": "ssh://git@git.lan/fleet"}, "robot1")
    assert "keepalive" not in default.to_json()  # the defaults: a robot's agent.json is as it was


def test_a_remote_that_stalls_over_ssh_is_given_up_after_the_keepalives(tmp_path, client_key):
    started = threading.Event()

    def answer(command: str):
        started.set()
        time.sleep(TIMEOUT)
        return b"", 0

    server = sshserver.ssh_server(client_key, answer)
    etc = tmp_path / "etc"
    etc.mkdir()
    client_key.write_private_key_file(str(etc / "id_ed25519"))
    (etc / "known_hosts").write_text(
        f"{agent_files.HOST_KEY_ALIAS} {server.host_key.get_name()} {server.host_key.get_base64()}\n"
    )
    with Link(server.port) as link:
        robot = transport.Remote(
            f"ssh://git@127.0.0.1:{link.port}/fleet", tmp_path / "releases", str(etc), TIMEOUT, keepalive=KEEPALIVE
        )
        failed: list = []

        def push():
            try:
                robot.push_report("robot1", report("robot1"))
            except transport.TransportError as error:
                failed.append(error)

        pushing = threading.Thread(target=push, daemon=True)
        pushing.start()
        assert started.wait(30), "the push did not reach the server"
        link.freeze()
        frozen_at = time.monotonic()
        pushing.join(TIMEOUT + 10)
        waited = time.monotonic() - frozen_at
    server.close()
    assert failed and str(failed[0]).startswith("report: "), failed
    assert waited < 2 + 8, f"given up {waited:.1f} s after the freeze"


@pytest.fixture(scope="module")
def tls(tmp_path_factory):
    return httpsgit.make_ca(tmp_path_factory.mktemp("tls"))


def test_a_remote_that_trickles_over_https_is_given_up_after_the_keepalives_silence(tmp_path, tls):
    ca, _, _ = tls
    server = httpsgit.Scripted(tls, b"HTTP/1.1 200 OK\r\nContent-Length: 100\r\n\r\n" + b"x" * 100, pace=5)
    etc = tmp_path / "etc"
    etc.mkdir()
    (etc / "remote-ca.pem").write_bytes(ca.read_bytes())
    robot = transport.Remote(
        f"https://127.0.0.1:{server.port}/fleet.git", tmp_path / "releases", str(etc), TIMEOUT, keepalive=KEEPALIVE
    )
    began = time.monotonic()
    try:
        with pytest.raises(transport.TransportError, match="^fetch: "):
            robot.fetch_releases()
    finally:
        server.close()
    assert time.monotonic() - began < 2 + 10


def test_the_operator_s_git_gets_the_same_bound_unless_its_ssh_is_the_user_s(tmp_path):
    """publish's pushes, status's report fetches (robotfleet/keepalive.py git_environment)."""
    repo = tmp_path / "clone"
    subprocess.run(["git", "init", "-q", str(repo)], check=True)
    env = keepalive.git_environment({"PATH": "/usr/bin:/bin"}, str(repo))
    assert env["GIT_SSH_COMMAND"] == "ssh -o ServerAliveInterval=15 -o ServerAliveCountMax=3"
    assert keepalive.git_environment({"GIT_SSH_COMMAND": "mine"}, str(repo)) == {"GIT_SSH_COMMAND": "mine"}
    other = tmp_path / "other"
    subprocess.run(["git", "init", "-q", str(other)], check=True)
    subprocess.run(["git", "-C", str(other), "config", "core.sshCommand", "ssh -i ~/.ssh/fleet"], check=True)
    assert "GIT_SSH_COMMAND" not in keepalive.git_environment({"PATH": "/usr/bin:/bin"}, str(other))
