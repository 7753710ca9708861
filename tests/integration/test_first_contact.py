"""First contact (issue 18, items 1 and 3): each host that cannot be reached
gives one line with the reason in words, within the connect timeout, and is
tried again only when trying again can help.  Real servers on 127.0.0.1
(tests/integration/sshserver.py): an SSH server, a listener that never speaks, a
closed port; connections go through the inventory and pyinfra's API, as
the CLI, status and rollout make them."""

from __future__ import annotations

import socket
import time

import paramiko

from robotfleet import hostkeys, reasons
from tests.fixtures import pyinfra
from tests.integration import sshserver
from tests.integration.operator_side import connect, fleet


def test_unknown_host_key_names_the_file_and_the_command_and_is_not_retried(tmp_path, monkeypatch, client_key):
    server = sshserver.ssh_server(client_key)
    try:
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}}, ssh_connect_retries=3)
        (tmp_path / "known_hosts").write_text("")
        line = connect(path, monkeypatch)["robot1"]
    finally:
        server.close()
    assert line == (
        f"unknown host key: [127.0.0.1]:{server.port} is not in {tmp_path}/known_hosts "
        "(ssh_strict_host_key_checking: yes); check and enroll it: "
        "robotfleet enroll inventories/robots.py --limit robot1"
    )
    assert server.connections == 1


def test_changed_host_key_is_refused_with_both_fingerprints(tmp_path, monkeypatch, client_key):
    server = sshserver.ssh_server(client_key)
    old = paramiko.ECDSAKey.generate()
    entry = f"[127.0.0.1]:{server.port}"
    try:
        hostkeys.append(str(tmp_path / "known_hosts"), entry, old)
        before = (tmp_path / "known_hosts").read_text()
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}}, ssh_connect_retries=3)
        line = connect(path, monkeypatch)["robot1"]
    finally:
        server.close()
    assert line.startswith(
        f"host key CHANGED: {tmp_path}/known_hosts has {hostkeys.fingerprint(old)} for {entry}, "
        f"the host offers {hostkeys.fingerprint(server.host_key)}; refused"
    )
    # the one instruction enroll gives too (issue 39 item 3): never trust the new key on first use
    assert line.endswith(
        "; refused (if the robot was reinstalled, record its new fingerprint and replace it: "
        "robotfleet enroll inventories/robots.py --replace robot1 --fingerprints FILE)"
    )
    assert (tmp_path / "known_hosts").read_text() == before
    assert server.connections == 1


def test_accept_new_writes_a_key_once(tmp_path, monkeypatch, client_key):
    """A rollout connects to a host several times in one process."""
    server = sshserver.ssh_server(client_key)
    try:
        path = fleet(
            tmp_path,
            {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}},
            ssh_strict_host_key_checking="accept-new",
        )
        assert connect(path, monkeypatch, times=3) == {"robot1": None}
        assert connect(path, monkeypatch, times=1) == {"robot1": None}
    finally:
        server.close()
    lines = (tmp_path / "known_hosts").read_text().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"[127.0.0.1]:{server.port} ecdsa-sha2-nistp256 ")


def test_authentication_failure_names_the_user_and_the_key(tmp_path, monkeypatch, client_key):
    server = sshserver.ssh_server(paramiko.ECDSAKey.generate())  # accepts another key
    try:
        path = fleet(
            tmp_path,
            {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}},
            ssh_strict_host_key_checking="accept-new",
            ssh_connect_retries=3,
        )
        line = connect(path, monkeypatch)["robot1"]
    finally:
        server.close()
    assert line == f"authentication failed for user ops with key {tmp_path}/id_fleet"
    assert server.connections == 1


def test_no_key_at_all_says_so(tmp_path, monkeypatch, client_key):
    server = sshserver.ssh_server(client_key)
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.ssh keys
    monkeypatch.delenv("SSH_AUTH_SOCK", raising=False)
    try:
        path = fleet(
            tmp_path,
            {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}},
            ssh_strict_host_key_checking="accept-new",
            ssh_key=None,
        )
        line = connect(path, monkeypatch)["robot1"]
    finally:
        server.close()
    assert line == (
        "authentication failed for user ops: no key to offer (ssh_key is not set, no SSH agent key, "
        "no key in ~/.ssh); set ssh_key to the fleet's private key"
    )


def test_wrong_hosts_fail_in_one_line_each_within_the_timeout(tmp_path, monkeypatch, client_key):
    with sshserver.wrong_hosts() as (silent, closed):
        path = fleet(
            tmp_path,
            {
                "silent": {"address": "127.0.0.1", "ssh_port": silent.port},
                "closed": {"address": "127.0.0.1", "ssh_port": closed},
            },
            ssh_connect_retries=1,
        )
        started = time.monotonic()
        lines = connect(path, monkeypatch)
        elapsed = time.monotonic() - started
    assert lines == {
        "silent": f"no SSH greeting: 127.0.0.1:{silent.port} accepted the connection but sent nothing "
        "within 2 s: a link that stalls (Wi-Fi, LTE), or not an SSH server (wrong port?)",
        "closed": f"connection refused by 127.0.0.1:{closed} (no SSH server listens on port {closed}) "
        "(tried 2 times: ssh_connect_retries: 1)",
    }
    assert silent.connections == 1  # not an SSH server: not tried again
    assert elapsed < 6, elapsed  # 2 s for the silent one, the refused one twice at once


def test_a_connection_closed_before_the_greeting_is_tried_again(tmp_path, monkeypatch, client_key):
    """sshd drops unauthenticated connections over MaxStartups: a retry helps there."""
    dropping = sshserver.Listener(hang_up=True)
    try:
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": dropping.port}}, ssh_connect_retries=2)
        line = connect(path, monkeypatch)["robot1"]
    finally:
        dropping.close()
    assert line == (
        f"connection closed by 127.0.0.1:{dropping.port} before the SSH greeting (an sshd turning "
        "connections away, e.g. MaxStartups, or a firewall) (tried 3 times: ssh_connect_retries: 2)"
    )
    assert dropping.connections == 3


def test_a_host_out_of_time_says_it_was_not_tried_again(tmp_path, monkeypatch, client_key):
    """ssh_connect_retries: 5, and the first try spent all of ssh_connect_timeout (issue 54, item 9)."""
    unanswered = sshserver.Unanswered()
    try:
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": unanswered.port}}, ssh_connect_retries=5)
        line = connect(path, monkeypatch)["robot1"]
    finally:
        unanswered.close()
    assert line == (
        f"timed out after 2 s connecting to 127.0.0.1:{unanswered.port} (no answer: powered off, wrong address or "
        "a firewall) (not tried again: ssh_connect_timeout: 2 s spent; ssh_connect_retries: 5)"
    )


def test_the_cli_prints_one_line_per_host_and_no_traceback(tmp_path, client_key):
    silent = sshserver.Listener()
    server = sshserver.ssh_server(client_key)
    try:
        path = fleet(
            tmp_path,
            {
                "silent": {"address": "127.0.0.1", "ssh_port": silent.port},
                "robot1": {"address": "127.0.0.1", "ssh_port": server.port},
            },
        )
        (tmp_path / "known_hosts").write_text("")
        result = pyinfra(
            "-y",
            "inventories/robots.py",
            "deploy.py",
            env={"PATH": "/usr/bin:/bin", "ROBOT_FLEET": str(path), "PYINFRA_PROGRESS": "off", "HOME": str(tmp_path)},
        )
    finally:
        silent.close()
        server.close()
    output = result.stdout + result.stderr
    assert "Traceback" not in output and "paramiko" not in output, output
    assert result.returncode != 0
    host_lines = [line.strip() for line in result.stderr.splitlines() if line.strip().startswith("[")]
    assert sorted(host_lines) == sorted(
        [
            f"[robot1] unknown host key: [127.0.0.1]:{server.port} is not in {tmp_path}/known_hosts "
            "(ssh_strict_host_key_checking: yes); check and enroll it: "
            "robotfleet enroll inventories/robots.py --limit robot1",
            f"[silent] no SSH greeting: 127.0.0.1:{silent.port} accepted the connection but sent nothing "
            "within 2 s: a link that stalls (Wi-Fi, LTE), or not an SSH server (wrong port?)",
        ]
    ), result.stderr


def handshake_cut_short(listener) -> tuple[paramiko.SSHException, paramiko.Transport]:
    """What a loaded machine can make of any handshake: paramiko's wait for it
    (start_client's timeout) ends before its wait for the greeting says why."""
    transport = paramiko.Transport(socket.create_connection(("127.0.0.1", listener.port), timeout=5))
    transport.banner_timeout = 5
    try:
        transport.start_client(timeout=0.5)
        try:
            transport.get_remote_server_key()
        except paramiko.SSHException as error:
            return error, transport
        raise AssertionError("the handshake finished")
    finally:
        transport.close()


def test_a_silent_port_is_named_so_when_paramikos_handshake_wait_ends_first():
    silent = sshserver.Listener()
    try:
        error, transport = handshake_cut_short(silent)
    finally:
        silent.close()
    assert str(error) == "No existing session" and not reasons.greeting_seen(transport)
    assert reasons.network_reason(error, "127.0.0.1", silent.port, 2, 2.0, reasons.greeting_seen(transport)) == (
        f"no SSH greeting: 127.0.0.1:{silent.port} accepted the connection but sent nothing within 2 s: "
        "a link that stalls (Wi-Fi, LTE), or not an SSH server (wrong port?)",
        False,
    )


def test_a_server_that_greets_then_stalls_is_a_cut_handshake():
    stalled = sshserver.Listener(greeting=b"SSH-2.0-OpenSSH_9.9\r\n")
    try:
        error, transport = handshake_cut_short(stalled)
    finally:
        stalled.close()
    assert str(error) == "No existing session" and reasons.greeting_seen(transport)
    assert reasons.network_reason(error, "127.0.0.1", stalled.port, 2, 2.0, reasons.greeting_seen(transport)) == (
        f"the SSH session to 127.0.0.1:{stalled.port} closed during the handshake",
        True,
    )
