"""robotfleet enroll (issue 18, item 1): host keys fetched from real
SSH servers on 127.0.0.1, shown as fingerprints, written once; a changed key
or a fingerprint that differs from the recorded one is refused and the file
is left as it was."""

from __future__ import annotations

import subprocess
import sys

import paramiko
import pytest

from robotfleet import hostkeys
from robotfleet.commands import enroll
from tests.fixtures import ROOT
from tests.integration import sshserver
from tests.integration.operator_side import connect, fleet


@pytest.fixture
def servers(client_key):
    started = [sshserver.ssh_server(client_key), sshserver.ssh_server(client_key)]
    yield started
    for server in started:
        server.close()


def run(path, monkeypatch, capsys, *args) -> tuple[int, list[str]]:
    monkeypatch.setenv("ROBOT_FLEET", str(path))
    monkeypatch.chdir(ROOT)
    code = enroll.main(["inventories/robots.py", *args])
    return code, capsys.readouterr().err.splitlines()


def two_robots(tmp_path, servers):
    return fleet(
        tmp_path, {f"robot{i + 1}": {"address": "127.0.0.1", "ssh_port": s.port} for i, s in enumerate(servers)}
    )


def line(server, name) -> str:
    return f"{name} ([127.0.0.1]:{server.port}) ecdsa-sha2-nistp256 {hostkeys.fingerprint(server.host_key)}"


def test_from_an_empty_known_hosts_to_a_strict_connection(tmp_path, monkeypatch, capsys, servers):
    path = two_robots(tmp_path, servers)
    known_hosts = tmp_path / "known_hosts"
    known_hosts.write_text("")
    code, lines = run(path, monkeypatch, capsys, "--yes")
    assert code == 0, lines
    assert lines[1:] == [
        f"{line(servers[0], 'robot1')}: new; enrolled (--yes)",
        f"{line(servers[1], 'robot2')}: new; enrolled (--yes)",
        f"{known_hosts}: 2 key(s) added",
        "enroll: 2 enrolled",
    ]
    assert connect(path, monkeypatch) == {"robot1": None, "robot2": None}  # strict checking passes
    written = known_hosts.read_text()
    code, lines = run(path, monkeypatch, capsys, "--yes")
    assert code == 0 and lines[-1] == "enroll: 2 known" and known_hosts.read_text() == written


def test_a_changed_key_is_refused_with_both_fingerprints_and_the_file_left_alone(
    tmp_path, monkeypatch, capsys, servers
):
    path = two_robots(tmp_path, servers)
    old = paramiko.ECDSAKey.generate()
    known_hosts = tmp_path / "known_hosts"
    hostkeys.append(str(known_hosts), f"[127.0.0.1]:{servers[0].port}", old)
    before = known_hosts.read_text()
    code, lines = run(path, monkeypatch, capsys, "--yes", "--limit", "robot1")
    assert code == 1
    assert lines[1] == (
        f"robot1: host key CHANGED for [127.0.0.1]:{servers[0].port}: {known_hosts} has "
        f"ecdsa-sha2-nistp256 {hostkeys.fingerprint(old)}, the host offers ecdsa-sha2-nistp256 "
        f"{hostkeys.fingerprint(servers[0].host_key)}; refused, its line is left as it is "
        "(if the robot was reinstalled, record its new fingerprint and replace it: robotfleet enroll "
        "inventories/robots.py --replace robot1 --fingerprints FILE)"
    )
    assert known_hosts.read_text() == before


def test_fingerprints_from_a_file_enroll_or_refuse(tmp_path, monkeypatch, capsys, servers):
    path = two_robots(tmp_path, servers)
    recorded = tmp_path / "fingerprints.txt"
    wrong = hostkeys.fingerprint(paramiko.ECDSAKey.generate())
    recorded.write_text(
        f"# from the image build\nrobot1 {hostkeys.fingerprint(servers[0].host_key)}\n"
        f"127.0.0.1 ecdsa-sha2-nistp256 {wrong}\n"
    )
    code, lines = run(path, monkeypatch, capsys, "--fingerprints", str(recorded))
    assert code == 1
    assert lines[1] == f"{line(servers[0], 'robot1')}: matches {recorded}; enrolled"
    assert lines[2] == (
        f"robot2: fingerprint mismatch for [127.0.0.1]:{servers[1].port}: {recorded} has {wrong}, "
        f"the host offers {hostkeys.fingerprint(servers[1].host_key)}; refused"
    )
    assert hostkeys.known(str(tmp_path / "known_hosts"), f"[127.0.0.1]:{servers[0].port}")
    assert not hostkeys.known(str(tmp_path / "known_hosts"), f"[127.0.0.1]:{servers[1].port}")


def test_a_host_missing_from_the_fingerprints_file_is_refused_even_with_yes(tmp_path, monkeypatch, capsys, servers):
    """Issue 27, item 9: --fingerprints FILE --yes enrolls only what FILE vouches for."""
    path = two_robots(tmp_path, servers)
    recorded = tmp_path / "fingerprints.txt"
    recorded.write_text(f"robot1 {hostkeys.fingerprint(servers[0].host_key)}\n")
    code, lines = run(path, monkeypatch, capsys, "--fingerprints", str(recorded), "--yes")
    assert code == 1
    assert lines[1:] == [
        f"{line(servers[0], 'robot1')}: matches {recorded}; enrolled",
        f"{line(servers[1], 'robot2')}: not in {recorded}; refused (a host missing from the "
        "fingerprints file is enrolled only with --allow-unlisted)",
        f"{tmp_path / 'known_hosts'}: 1 key(s) added",
        "enroll: 1 enrolled, 1 refused",
    ]
    assert not hostkeys.known(str(tmp_path / "known_hosts"), f"[127.0.0.1]:{servers[1].port}")
    # Asked for by name: the unlisted host is taken as shown (--yes).
    code, lines = run(path, monkeypatch, capsys, "--fingerprints", str(recorded), "--yes", "--allow-unlisted")
    assert code == 0 and lines[2] == f"{line(servers[1], 'robot2')}: new; enrolled (--yes)"
    assert hostkeys.known(str(tmp_path / "known_hosts"), f"[127.0.0.1]:{servers[1].port}")


def test_replace_takes_a_reflashed_robots_new_key_only_when_it_matches_the_file(tmp_path, monkeypatch, capsys, servers):
    """Issue 28, item 9: the way back for a reflashed robot, without editing
    known_hosts by hand; what was replaced is said with both fingerprints."""
    path = two_robots(tmp_path, servers)
    known_hosts = tmp_path / "known_hosts"
    entry1, entry2 = f"[127.0.0.1]:{servers[0].port}", f"[127.0.0.1]:{servers[1].port}"
    old = paramiko.ECDSAKey.generate()
    hashed = paramiko.HostKeys.hash_host(entry1)
    known_hosts.write_text(
        f"# the fleet\n{hashed} {old.get_name()} {old.get_base64()}\n"
        f"{entry2},{entry1} {old.get_name()} {old.get_base64()}\n"
        f"@cert-authority *.fleet {old.get_name()} {old.get_base64()}\n"
    )
    before = known_hosts.read_text()
    new_print, old_print = hostkeys.fingerprint(servers[0].host_key), hostkeys.fingerprint(old)
    recorded = tmp_path / "fingerprints.txt"

    recorded.write_text(f"robot1 {hostkeys.fingerprint(paramiko.ECDSAKey.generate())}\n")
    code, lines = run(path, monkeypatch, capsys, "--replace", "robot1", "--fingerprints", str(recorded))
    assert code == 1 and known_hosts.read_text() == before
    assert lines[1].startswith(
        f"robot1: host key CHANGED for {entry1}: {known_hosts} has ecdsa-sha2-nistp256 {old_print}"
    )
    assert lines[1].endswith(": not replaced, its line is left as it is")

    recorded.write_text(f"robot1 {new_print}\n")
    code, lines = run(path, monkeypatch, capsys, "--replace", "robot1", "--fingerprints", str(recorded))
    assert code == 0, lines
    assert lines[1:] == [
        f"robot1 ({entry1}): host key replaced: was ecdsa-sha2-nistp256 {old_print}, now "
        f"ecdsa-sha2-nistp256 {new_print} (matches {recorded})",
        "enroll: 1 replaced",
    ]
    text = known_hosts.read_text().splitlines()
    assert text[0] == "# the fleet" and hashed not in "\n".join(text)
    assert text[1] == f"{entry2} {old.get_name()} {old.get_base64()}"  # robot2's name on the shared line stays
    assert text[2].startswith("@cert-authority *.fleet ")
    assert hostkeys.known(str(known_hosts), entry1) == {servers[0].host_key.get_name(): servers[0].host_key}
    assert connect(path, monkeypatch)["robot1"] is None  # strict checking passes again


def test_replace_needs_a_fingerprints_file_and_a_host_of_the_inventory(tmp_path, monkeypatch, capsys, servers):
    path = two_robots(tmp_path, servers)
    code, lines = run(path, monkeypatch, capsys, "--replace", "robot1", "--yes")
    assert code == 2 and lines == [
        "--replace needs --fingerprints FILE: a changed key is replaced only when it "
        "matches the fingerprint recorded for the host; nothing was done"
    ]
    recorded = tmp_path / "fingerprints.txt"
    recorded.write_text("")
    code, lines = run(path, monkeypatch, capsys, "--replace", "robot9", "--fingerprints", str(recorded))
    assert code == 2 and lines == ["--replace robot9: no such host in inventories/robots.py; nothing was done"]


def test_without_a_terminal_nothing_is_enrolled_unasked(tmp_path, monkeypatch, capsys, servers):
    path = two_robots(tmp_path, servers)
    monkeypatch.setattr(sys, "stdin", open("/dev/null"))
    code, lines = run(path, monkeypatch, capsys, "--limit", "robot2")
    assert code == 1
    assert lines[1] == (
        f"{line(servers[1], 'robot2')}: new; not enrolled: no terminal to ask (check the "
        "fingerprint, then pass --yes, or give --fingerprints FILE)"
    )
    assert not (tmp_path / "known_hosts").exists()


def test_asking_shows_the_fingerprint_and_takes_the_answer(tmp_path, servers):
    """A person at a terminal (a pty): y enrolls robot1, n declines robot2."""
    import os
    import pty
    import select
    import time

    path = two_robots(tmp_path, servers)
    env = {"PATH": "/usr/bin:/bin", "ROBOT_FLEET": str(path), "HOME": str(tmp_path)}
    main, terminal = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "robotfleet", "enroll", "inventories/robots.py"],
        cwd=ROOT,
        env=env,
        stdin=terminal,
        stdout=terminal,
        stderr=terminal,
    )
    os.close(terminal)
    seen, answers, deadline = b"", [b"y\n", b"n\n"], time.monotonic() + 60
    while proc.poll() is None and time.monotonic() < deadline:
        if select.select([main], [], [], 0.2)[0]:
            try:
                seen += os.read(main, 4096)
            except OSError:
                break
            if seen.rstrip().endswith(b"[y/N]") and answers:
                os.write(main, answers.pop(0))
    proc.wait(timeout=10)
    text = seen.decode()
    assert f"{line(servers[0], 'robot1')}: new. Is this the robot's key? [y/N] " in text, text
    assert proc.returncode == 1  # robot2 declined
    assert hostkeys.known(str(tmp_path / "known_hosts"), f"[127.0.0.1]:{servers[0].port}")
    assert not hostkeys.known(str(tmp_path / "known_hosts"), f"[127.0.0.1]:{servers[1].port}")


def test_unreachable_and_unmatched(tmp_path, monkeypatch, capsys):
    closed = sshserver.closed_port()
    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": closed}})
    code, lines = run(path, monkeypatch, capsys, "--yes")
    assert code == 3
    assert lines[1] == (
        f"robot1: unreachable: connection refused by 127.0.0.1:{closed} (no SSH server listens on port {closed})"
    )
    code, lines = run(path, monkeypatch, capsys, "--limit", "bot-z")
    assert code == 2
    assert lines == [
        "--limit bot-z: no host or group of inventories/robots.py matches (hosts: robot1; "
        "groups: robots); nothing was done"
    ]


def test_the_command_is_listed():
    result = subprocess.run([sys.executable, "-m", "robotfleet"], cwd=ROOT, capture_output=True, text=True)
    assert "robotfleet enroll INVENTORY" in result.stderr


def test_a_fingerprints_file_that_is_missing_or_holds_a_bogus_fingerprint_is_one_line(
    tmp_path, monkeypatch, capsys, servers
):
    """Issue 39 item 9: no bare [Errno 2], and SHA256:abc is not a fingerprint (43 base64 characters)."""
    path = two_robots(tmp_path, servers)
    missing = tmp_path / "missing.txt"
    code, lines = run(path, monkeypatch, capsys, "--fingerprints", str(missing))
    assert (code, lines) == (
        2,
        [
            f"--fingerprints {missing}: No such file or directory; give the file of the hosts' "
            "recorded fingerprints (HOST SHA256:... a line); nothing was done"
        ],
    )
    bogus = tmp_path / "fingerprints.txt"
    bogus.write_text(f"robot1 {hostkeys.fingerprint(servers[0].host_key)}\nrobot2 SHA256:abc\n")
    code, lines = run(path, monkeypatch, capsys, "--fingerprints", str(bogus), "--yes")
    assert (code, lines) == (
        2,
        [
            f"{bogus}: line 2: 'SHA256:abc' is not a SHA256 fingerprint (SHA256: and 43 base64 "
            "characters, as ssh-keygen -lf shows it); nothing was done"
        ],
    )
    assert not (tmp_path / "known_hosts").exists()  # nothing was enrolled
