"""The fleet's known_hosts as OpenSSH reads it, and host certificates
checked with OpenSSH (issue 27, item 13).  paramiko gives up on a whole
known_hosts file at its first `@cert-authority` line; robotfleet reads it
itself: plain keys, `@revoked` keys refused, and a host an `@cert-authority`
line covers is checked with OpenSSH's ssh, never trusted on first use.
Connections go to real SSH servers on 127.0.0.1 (tests/integration/sshserver.py,
which offers no certificate; tests/integration/certserver.py, which presents
certificates ssh-keygen made) and to hostile servers that write ssh's words
into its log (issue 36, item 1); a robot whose sshd presents a signed host
key is tests/e2e/test_hostcerts.py's."""

from __future__ import annotations

import socket
import struct
import threading

import paramiko
import pytest

from robotfleet import hostcerts, hostkeys
from tests.integration import certserver, sshserver
from tests.integration.operator_side import connect, fleet


def line(names: str, key, marker: str = "") -> str:
    return f"{marker + ' ' if marker else ''}{names} {key.get_name()} {key.get_base64()}\n"


@pytest.fixture
def server(client_key):
    started = sshserver.ssh_server(client_key)
    yield started
    started.close()


def test_a_known_hosts_with_marker_lines_is_read_whole(tmp_path):
    ca, robot1, robot2, revoked = (paramiko.ECDSAKey.generate() for _ in range(4))
    path = tmp_path / "known_hosts"
    path.write_text(
        "# fleet\n"
        + line("*.fleet,!bad.fleet", ca, "@cert-authority")
        + "not a key line\n"
        + line("[10.0.0.1]:2222", robot1)
        + line("*", revoked, "@revoked")
        + line(paramiko.HostKeys.hash_host("robot2.fleet"), robot2)
        + line("robot3.fleet", revoked)
    )
    with pytest.raises(paramiko.hostkeys.InvalidHostKey):  # paramiko (pyinfra's reader) gives up on the file
        paramiko.HostKeys(str(path))
    known = hostkeys.read(str(path))
    assert known.plain.lookup("[10.0.0.1]:2222") == {robot1.get_name(): robot1}
    assert known.usable().lookup("robot2.fleet") == {robot2.get_name(): robot2}  # a hashed name
    assert known.usable().lookup("robot3.fleet") is None  # a revoked key is never a known one
    assert known.revoked_key(revoked) and not known.revoked_key(robot1)
    assert known.authorities_for("robot7.fleet") == [ca]
    assert known.authorities_for("bad.fleet") == [] and known.authorities_for("robot7.lan") == []
    assert hostkeys.matches(["[10.0.0.*]:2222"], "[10.0.0.9]:2222")
    assert not hostkeys.matches(["10.0.0.*"], "[10.0.0.9]:2222")


def test_a_plain_line_after_a_ca_line_still_counts(tmp_path, monkeypatch, server):
    """paramiko stops reading at the CA line: the host's own line after it
    would be lost and the host refused as unknown."""
    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}})
    (tmp_path / "known_hosts").write_text(
        line("*", paramiko.ECDSAKey.generate(), "@cert-authority") + line(f"[127.0.0.1]:{server.port}", server.host_key)
    )
    assert connect(path, monkeypatch) == {"robot1": None}


def test_a_revoked_key_is_refused_though_a_plain_line_names_it(tmp_path, monkeypatch, server):
    path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}})
    (tmp_path / "known_hosts").write_text(
        line(f"[127.0.0.1]:{server.port}", server.host_key) + line("*", server.host_key, "@revoked")
    )
    assert connect(path, monkeypatch) == {
        "robot1": (
            f"host key REVOKED: {server.host_key.get_name()} {hostkeys.fingerprint(server.host_key)} is marked "
            f"@revoked in {tmp_path / 'known_hosts'}; refused"
        )
    }


@pytest.mark.parametrize("strictness", ["yes", "accept-new"])
def test_a_host_a_ca_line_covers_is_checked_by_openssh_and_never_trusted_on_first_use(
    tmp_path, monkeypatch, server, strictness
):
    """The server offers no certificate: refused with ssh's reason, and with
    accept-new its key is still not written (no fall-back to first use)."""
    path = fleet(
        tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}}, ssh_strict_host_key_checking=strictness
    )
    known_hosts = tmp_path / "known_hosts"
    known_hosts.write_text(line("[127.0.0.1]:*", paramiko.ECDSAKey.generate(), "@cert-authority"))
    before = known_hosts.read_text()
    (reason,) = connect(path, monkeypatch).values()
    assert reason == (
        "host certificate refused: it offers no host certificate for that key (sshd_config HostCertificate)"
    )
    assert known_hosts.read_text() == before


def test_a_missing_krl_refuses_rather_than_skipping_the_check(tmp_path, monkeypatch, server):
    path = fleet(
        tmp_path,
        {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}},
        ssh_revoked_host_keys=str(tmp_path / "missing.krl"),
    )
    (tmp_path / "known_hosts").write_text(line("*", paramiko.ECDSAKey.generate(), "@cert-authority"))
    assert connect(path, monkeypatch) == {
        "robot1": f"host certificate refused: the KRL {tmp_path / 'missing.krl'} (ssh_revoked_host_keys) is missing"
    }


def test_the_openssh_check_is_strict_stops_before_a_login_and_asks_for_a_certificate():
    argv = hostcerts.command("10.0.0.7", 2222, "ops", "ssh-ed25519", "inventories/known_hosts", "fleet.krl", 10)
    options = dict(argv[i + 1].split("=", 1) for i, word in enumerate(argv) if word == "-o")
    assert options["StrictHostKeyChecking"] == "yes" and options["BatchMode"] == "yes"
    assert options["HostKeyAlgorithms"] == "ssh-ed25519-cert-v01@openssh.com"
    assert options["UserKnownHostsFile"] == "inventories/known_hosts" and options["GlobalKnownHostsFile"] == "/dev/null"
    assert options["RevokedHostKeys"] == "fleet.krl" and options["PreferredAuthentications"] == "none"
    assert options["IdentityAgent"] == "none" and options["IdentityFile"] == "none"
    assert argv[-3:] == ["--", "10.0.0.7", "true"] and ["-F", "/dev/null"] == argv[2:4]


# What OpenSSH 9.2's ssh -v says (recorded from a lab robot's sshd).
SEEN = (
    "debug1: Server host certificate: ssh-ed25519-cert-v01@openssh.com "
    "SHA256:wKn6CpIpmtmV7QDGvN7MBubrawtM6AGVC8W4SwGaddY, "
    'serial 3 ID "robot1" CA ssh-ed25519 SHA256:5xnEYyTupH0h60yO1pULarYdTK7Z9rrexDS7mTkj4y8 valid from '
    "2020-01-01T00:00:00 to 2020-02-01T00:00:00\n"
    "debug1: Host '[127.0.0.1]:22009' is known and matches the ED25519-CERT host certificate.\n"
    "debug1: Found CA key in kh:1\n"
)
FAILED = (
    "debug1: No matching CA found. Retry with plain key\n"
    "No ED25519 host key is known for [127.0.0.1]:22009 and you have requested strict checking.\n"
    "Host key verification failed.\n"
)
ABOUT = " (certificate 'robot1', serial 3, valid from 2020-01-01T00:00:00 to 2020-02-01T00:00:00)"


@pytest.mark.parametrize(
    "output, reason",
    [
        (
            SEEN
            + "debug1: Authentications that can continue: publickey\nops@127.0.0.1: Permission denied (publickey).\n",
            "the certificate check with ssh failed: ops@127.0.0.1: Permission denied (publickey).",
        ),
        (SEEN + "Certificate invalid: expired\n" + FAILED, "its host certificate is invalid: expired" + ABOUT),
        (
            SEEN + "Certificate invalid: name is not a listed principal\n" + FAILED,
            "its host certificate is invalid: 127.0.0.1 is not one of its principals" + ABOUT,
        ),
        (
            SEEN.split("debug1: Host")[0] + "Host key ED25519-CERT SHA256:wKn6 revoked by file /f/krl\n"
            "Host key verification failed.\n",
            "its host key is revoked by the KRL /f/krl" + ABOUT,
        ),
        (
            SEEN.split("debug1: Host")[0] + FAILED,
            "its host certificate is signed by CA SHA256:5xnEYyTupH0h60yO1pULarYdTK7Z9rrexDS7mTkj4y8, "
            "which no @cert-authority line of kh trusts for it" + ABOUT,
        ),
        (
            "Unable to negotiate with 127.0.0.1 port 2: no matching host key type found. Their offer: ssh-ed25519\n",
            "it offers no host certificate for that key (sshd_config HostCertificate)",
        ),
        (
            "ssh: connect to host 127.0.0.1 port 2: Connection refused\n",
            "the certificate check with ssh failed: ssh: connect to host 127.0.0.1 port 2: Connection refused",
        ),
    ],
    ids=["acceptance in words only", "expired", "principal", "revoked", "another CA", "no certificate", "refused"],
)
def test_what_ssh_said_is_only_ever_a_reason_to_refuse(output, reason):
    """ssh's log never accepts a host (a server can write ssh's words into
    it): words that say ssh accepted a certificate are one more refusal."""
    assert hostcerts.refusal(output, "127.0.0.1", "kh") == reason


@pytest.fixture
def ca(tmp_path):
    (tmp_path / "ca").mkdir()
    return certserver.HostCA(tmp_path / "ca")


@pytest.fixture
def certified(tmp_path, monkeypatch, client_key, ca):
    """Connect robot1, a server presenting ``certificate`` (its plain key
    ``offered`` to paramiko, by default the certified one), with the CA
    ``trusted`` in the fleet's known_hosts: (its connection error, the server)."""
    started = []

    def run(certificate, trusted=ca, offered=None, greeting=b"", **settings):
        server = certserver.CertifiedServer(certificate, client_key, offered, greeting)
        started.append(server)
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}}, **settings)
        known_hosts = tmp_path / "known_hosts"
        known_hosts.write_text(trusted.line("[127.0.0.1]:*"))
        (outcome,) = connect(path, monkeypatch).values()
        assert known_hosts.read_text() == trusted.line("[127.0.0.1]:*")  # nothing ever written
        return outcome, server

    yield run
    for server in started:
        server.close()


def test_a_robot_whose_certificate_a_trusted_ca_signed_is_connected(certified, ca):
    assert certified(ca.host_key("robot1"))[0] is None


def test_a_certificate_of_another_key_than_the_one_paramiko_sees_is_refused(certified, ca):
    """A man in the middle relays ssh's check to the real robot and offers
    paramiko its own key (of the same type)."""
    own = certserver.private_key(ca.host_key("mitm"))
    outcome, server = certified(ca.host_key("robot1"), offered=own)
    assert outcome == (
        f"host certificate refused: it certifies {hostkeys.fingerprint(server.certified.key)}, "
        f"but this connection was offered {own.get_name()} {hostkeys.fingerprint(own)}"
    )


def test_expired_wrong_principal_revoked_and_another_cas_certificates_are_refused(certified, ca, tmp_path):
    valid = "valid from 2020-01-01T00:00:00 to 2020-02-01T00:00:00"
    assert certified(ca.host_key("old", validity="20200101:20200201"))[0] == (
        f"host certificate refused: its host certificate is invalid: expired (certificate 'old', serial 3, {valid})"
    )
    outcome, _ = certified(ca.host_key("named", principals="robot1.fleet"))
    assert outcome.startswith(
        "host certificate refused: its host certificate is invalid: 127.0.0.1 is not one of "
        "its principals (certificate 'named', serial 3, valid from "
    )
    revoked = ca.host_key("revoked")
    certserver.keygen("-k", "-f", str(tmp_path / "fleet.krl"), str(revoked))
    outcome, _ = certified(revoked, ssh_revoked_host_keys=str(tmp_path / "fleet.krl"))
    assert outcome.startswith(
        f"host certificate refused: its host key is revoked by the KRL {tmp_path / 'fleet.krl'} "
        "(certificate 'revoked', serial 3, valid from "
    )
    (tmp_path / "other").mkdir()
    outcome, _ = certified(ca.host_key("robot1"), trusted=certserver.HostCA(tmp_path / "other"))
    assert outcome.startswith("host certificate refused: its host certificate is signed by CA SHA256:")


def forged(fingerprint: str) -> list[str]:
    """What the old check took for ssh accepting a certificate of the key
    ``fingerprint``: ssh's own words, as a server writes them."""
    return [
        f'debug1: Server host certificate: ssh-ed25519-cert-v01@openssh.com {fingerprint}, serial 1 ID "robot1" '
        "CA ssh-ed25519 SHA256:5xnEYyTupH0h60yO1pULarYdTK7Z9rrexDS7mTkj4y8 valid forever",
        "debug1: Host '[127.0.0.1]:22' is known and matches the ED25519-CERT host certificate.",
        "debug1: Authentications that can continue: publickey",
        "ops@127.0.0.1: Permission denied (publickey).",
    ]


def test_lines_a_server_sends_before_its_banner_never_pass_for_ssh_accepting_a_certificate(
    tmp_path, monkeypatch, client_key
):
    """The server offers a plain key and no certificate, after ssh's words
    (ssh -v logs the lines a server sends before its version banner)."""
    key = paramiko.ECDSAKey.generate()
    greeting = "".join(line + "\r\n" for line in forged(hostkeys.fingerprint(key))).encode()
    server = sshserver.Listener(host_key=key, client_key=client_key, greeting=greeting)
    try:
        path = fleet(tmp_path, {"robot1": {"address": "127.0.0.1", "ssh_port": server.port}})
        (tmp_path / "known_hosts").write_text(line("[127.0.0.1]:*", paramiko.ECDSAKey.generate(), "@cert-authority"))
        assert connect(path, monkeypatch) == {
            "robot1": "host certificate refused: it offers no host certificate "
            "for that key (sshd_config HostCertificate)"
        }
    finally:
        server.close()


def _packet(payload: bytes) -> bytes:
    """An SSH packet before any key is agreed (RFC 4253, section 6)."""
    padding = 8 - (len(payload) + 5) % 8 + (8 if 8 - (len(payload) + 5) % 8 < 4 else 0)
    return struct.pack(">IB", len(payload) + padding + 1, padding) + payload + bytes(padding)


def _string(data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + data


def test_whole_lines_a_server_writes_during_the_key_exchange_never_pass_for_ssh_accepting_a_certificate(tmp_path):
    """SSH_MSG_DEBUG and SSH_MSG_DISCONNECT are logged with their newlines:
    a server writes whole lines that look like ssh's own."""
    key = paramiko.Ed25519Key(filename=str(certserver.HostCA(tmp_path).host_key("robot1")).removesuffix("-cert.pub"))
    words = "\n".join(["x", *forged(hostkeys.fingerprint(key))]).encode()
    listener = socket.create_server(("127.0.0.1", 0))

    def hostile():
        conn, _ = listener.accept()
        with conn:
            conn.sendall(
                b"SSH-2.0-OpenSSH_9.2\r\n"
                + _packet(b"\x04\x01" + _string(words) + _string(b""))
                + _packet(b"\x01" + struct.pack(">I", 11) + _string(words) + _string(b""))
            )
            conn.recv(65536)

    threading.Thread(target=hostile, daemon=True).start()
    (tmp_path / "known_hosts").write_text(line("[127.0.0.1]:*", paramiko.ECDSAKey.generate(), "@cert-authority"))
    try:
        verdict = hostcerts.verify(
            "127.0.0.1", listener.getsockname()[1], "ops", "ssh-ed25519", str(tmp_path / "known_hosts"), None, 5
        )
    finally:
        listener.close()
    assert verdict.fingerprint is None
    assert verdict.reason.startswith("the certificate check with ssh failed: ") and "\n" not in verdict.reason
