"""Messages and exit codes that tell the truth (issue 28, item 11): each
reason a host cannot be reached claims only what happened (a service that
answered with something else is not "silent for 10 s", a timeout is said
after that long), and each robotfleet exit code is README's ("Exit codes":
1 a host failed, its host key not trusted or its login refused among them;
2 refused; 3 unreachable and nothing failed).  Real servers on 127.0.0.1."""

from __future__ import annotations

import json
import time

import paramiko
import pytest

from robotfleet import hostkeys
from tests.integration import sshserver
from tests.integration.operator_side import connect, fleet, run


@pytest.fixture(autouse=True)
def key(client_key):
    return client_key


def timed_connect(path, monkeypatch):
    started = time.monotonic()
    line = connect(path, monkeypatch)["robot1"]
    return line, time.monotonic() - started


def test_a_service_that_answers_otherwise_is_not_called_silent(tmp_path, monkeypatch):
    """paramiko gives up 2 s after a first line that is not SSH's: the line
    used to say "sent no SSH greeting within 10 s" then."""
    mail = sshserver.Listener(greeting=b"220 mail.example.com ESMTP Postfix\r\n")
    try:
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": mail.port}}, ssh_connect_timeout=10)
        line, elapsed = timed_connect(path, monkeypatch)
    finally:
        mail.close()
    assert line == (
        f"not an SSH server: 127.0.0.1:{mail.port} answered, but not with an SSH greeting (another "
        "service on that port? wrong port?)"
    )
    assert elapsed < 10
    assert mail.connections == 1


def test_a_silent_listener_is_said_silent_after_the_time_it_claims(tmp_path, monkeypatch):
    silent = sshserver.Listener()
    try:
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": silent.port}}, ssh_connect_timeout=2)
        line, elapsed = timed_connect(path, monkeypatch)
    finally:
        silent.close()
    assert line == (
        f"no SSH greeting: 127.0.0.1:{silent.port} accepted the connection but sent nothing "
        "within 2 s: a link that stalls (Wi-Fi, LTE), or not an SSH server (wrong port?)"
    )
    assert 2 <= elapsed < 3


def test_a_timeout_is_said_after_that_long(tmp_path, monkeypatch):
    dark = sshserver.Unanswered()
    try:
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": dark.port}}, ssh_connect_timeout=2)
        line, elapsed = timed_connect(path, monkeypatch)
    finally:
        dark.close()
    assert line.startswith(f"timed out after 2 s connecting to 127.0.0.1:{dark.port} ")
    assert 2 <= elapsed < 3


def test_a_missing_key_file_is_named(tmp_path, monkeypatch):
    server = sshserver.ssh_server()
    try:
        path = fleet(
            tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}}, ssh_key=str(tmp_path / "nowhere")
        )
        line, _ = timed_connect(path, monkeypatch)
    finally:
        server.close()
    assert line == f"cannot connect: No such private key file: {tmp_path}/nowhere"
    assert not (tmp_path / "nowhere").exists() and server.connections == 0


def status(tmp_path, hosts: dict, **common):
    path = fleet(tmp_path, hosts, ssh_connect_retries=0, ssh_strict_host_key_checking="yes", **common)
    result = run(path, tmp_path, "-m", "robotfleet", "status", "inventories/robots.py", "--json")
    rows = json.loads(result.stdout) if result.stdout.strip() else []
    return result.returncode, {row["host"]: row.get("error") for row in rows}, result


def trusted(tmp_path, server, key=None):
    """known_hosts with ``server``'s key (or ``key`` in its place)."""
    hostkeys.append(str(tmp_path / "known_hosts"), f"[127.0.0.1]:{server.port}", key or server.host_key)


def test_status_exit_codes_are_readmes(tmp_path, client_key):
    good = sshserver.ssh_server(client_key)
    changed = sshserver.ssh_server(client_key)
    unknown = sshserver.ssh_server(client_key)
    refusing = sshserver.ssh_server(paramiko.ECDSAKey.generate())
    closed = sshserver.closed_port()
    try:
        (tmp_path / "known_hosts").write_text("")
        for server in (good, refusing):
            trusted(tmp_path, server)
        trusted(tmp_path, changed, paramiko.ECDSAKey.generate())

        def case(*names, **servers):
            hosts = {name: {"address": "127.0.0.1", "ssh_port": port} for name, port in servers.items()}
            code, errors, result = status(tmp_path, hosts)
            assert sorted(errors) == sorted(names), result.stderr
            return code, errors

        assert case("robot1", robot1=good.port) == (0, {"robot1": None})
        code, errors = case("robot1", robot1=closed)
        assert code == 3 and errors["robot1"].startswith("connection refused")
        code, errors = case("robot1", robot1=changed.port)
        assert code == 1 and errors["robot1"].startswith("host key CHANGED")
        assert status(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": changed.port}})[2].stderr.startswith(
            "[robot1] failed: host key CHANGED: "
        )  # reached, and refused: not "unreachable"
        code, errors = case("robot1", robot1=unknown.port)
        assert code == 1 and errors["robot1"].startswith("unknown host key")
        code, errors = case("robot1", robot1=refusing.port)
        assert code == 1 and errors["robot1"].startswith("authentication failed")
        # a host that failed outweighs one that was unreachable
        assert case("robot1", "robot2", robot1=changed.port, robot2=closed)[0] == 1
    finally:
        for server in (good, changed, unknown, refusing):
            server.close()


def test_status_refusals_exit_2(tmp_path):
    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": 1}})
    assert run(path, tmp_path, "-m", "robotfleet", "status", "inventories/nothing.py").returncode == 2
    assert run(path, tmp_path, "-m", "robotfleet", "status", "inventories/robots.py", "--limit", "x").returncode == 2
    path.write_text("robots: {hosts: {robot1: {docker_usres: []}}}\n")
    assert run(path, tmp_path, "-m", "robotfleet", "status", "inventories/robots.py").returncode == 2


def test_a_rollout_over_a_robot_whose_host_key_changed_fails(tmp_path, client_key):
    """README: a changed host key is a failure (1); it was counted as an
    unreachable robot, skipped (3)."""
    changed = sshserver.ssh_server(client_key)
    try:
        (tmp_path / "known_hosts").write_text("")
        trusted(tmp_path, changed, paramiko.ECDSAKey.generate())
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": changed.port}}, ssh_connect_retries=0)
        result = run(path, tmp_path, "-m", "robotfleet", "rollout", "inventories/robots.py", "-y")
        dry = run(path, tmp_path, "-m", "robotfleet", "rollout", "inventories/robots.py", "--dry")
    finally:
        changed.close()
    assert dry.returncode == 1, dry.stderr[-3000:]
    assert dry.stderr.splitlines()[-1] == (
        "rollout: dry run incomplete: 1 robot(s) refused (host key or login), not planned: robot1"
    )
    assert result.returncode == 1, result.stderr[-3000:]
    assert "rollout: [robot1] failed: host key CHANGED: " in result.stderr, result.stderr[-3000:]


def test_the_laptops_sudo_lines_say_what_happened_and_the_ways_on():
    """The pure part of robotfleet/localsudo.py (the real sudo: tests/e2e/test_laptop_sudo.py)."""
    from robotfleet import localsudo

    assert localsudo.problem("@local", "dev", "ok", "", terminal=False) is None
    assert localsudo.problem("@local", "dev", "password", "sudo: a password is required", terminal=True) is None
    line = localsudo.problem("@local", "dev", "password", "sudo: a password is required", terminal=False)
    assert line.startswith("[@local] sudo needs a password for dev, and there is no terminal to ask for it: ")
    assert "--use-sudo-password" in line and "echo 'dev ALL=(ALL:ALL) NOPASSWD: ALL' | sudo tee" in line
    assert localsudo.problem("@local", "dev", "missing", "sudo is not installed", terminal=True).startswith(
        "[@local] sudo is not installed"
    )
    assert localsudo.problem("@local", "dev", "refused", "sudo: account validation failure", terminal=True) == (
        "[@local] sudo refuses dev: sudo: account validation failure"
    )
