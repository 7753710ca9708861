"""SSH host certificates, checked by OpenSSH on the operator's machine.

pyinfra 3.10 connects through paramiko, which cannot read ``@cert-authority``
lines (and gives up on the whole known_hosts file at the first one) and does
not ask a server for its certificate.  So when a host has no plain key in the
fleet's known_hosts but an ``@cert-authority`` line matches it, OpenSSH's own
``ssh`` checks it: one connection that stops before logging in (no command
runs), with the fleet's known_hosts, strict checking, only the certificate
type of the key paramiko was offered, and the fleet's KRL
(``ssh_revoked_host_keys``).  ssh checks the CA, the principals (the address
connected to), the validity period, the KRL and ``@revoked`` lines; the plain
key inside the certificate it accepted (its fingerprint) is then the one key
paramiko may accept for that host, in memory, for this run: paramiko's own
handshake proves the host holds that key.  Anything else is refused with
ssh's reason; there is no fall-back to trust on first use.

Which certificate ssh accepted is never read from its log: a server writes
into it whatever it likes (lines before its version banner, and whole lines,
newlines included, in debug and disconnect messages during the key
exchange).  ssh's agent is a socket of ours instead, which only ssh knows:
OpenSSH (8.9 and later) asks its agent for keys only once the server's host
key is accepted, and first tells it that key (``session-bind@openssh.com``).
The log only explains a refusal.
"""

from __future__ import annotations

import base64
import hashlib
import os
import re
import socket
import subprocess
import tempfile
import threading
from dataclasses import dataclass

import paramiko

# The certificate algorithms for each plain key type paramiko may be offered.
CERT_ALGORITHMS = {
    "ssh-ed25519": "ssh-ed25519-cert-v01@openssh.com",
    "ecdsa-sha2-nistp256": "ecdsa-sha2-nistp256-cert-v01@openssh.com",
    "ecdsa-sha2-nistp384": "ecdsa-sha2-nistp384-cert-v01@openssh.com",
    "ecdsa-sha2-nistp521": "ecdsa-sha2-nistp521-cert-v01@openssh.com",
    "ssh-rsa": "rsa-sha2-512-cert-v01@openssh.com,rsa-sha2-256-cert-v01@openssh.com",
}
# The key class of each certificate type a certificate blob names.
_CERT_KEYS = {
    "ssh-ed25519-cert-v01@openssh.com": paramiko.Ed25519Key,
    "ecdsa-sha2-nistp256-cert-v01@openssh.com": paramiko.ECDSAKey,
    "ecdsa-sha2-nistp384-cert-v01@openssh.com": paramiko.ECDSAKey,
    "ecdsa-sha2-nistp521-cert-v01@openssh.com": paramiko.ECDSAKey,
    "ssh-rsa-cert-v01@openssh.com": paramiko.RSAKey,
}
# Lines ssh writes at their start (a server's text before its banner is
# logged after a prefix of ssh's, "kex_exchange_identification: banner line").
_CERTIFICATE = re.compile(
    r'^debug1: Server host certificate: \S+ (SHA256:[A-Za-z0-9+/]+),? serial (\d+) ID "(.*)" '
    r"CA \S+ (SHA256:[A-Za-z0-9+/]+) valid (.*)$",
    re.M,
)
_INVALID = re.compile(r"^Certificate invalid: (.*)", re.M)
# ssh-agent protocol (draft-miller-ssh-agent): what ssh sends, what we answer.
_REQUEST_IDENTITIES, _IDENTITIES_ANSWER, _EXTENSION, _SUCCESS, _FAILURE = 11, 12, 27, 6, 5
_SESSION_BIND = b"session-bind@openssh.com"
_MAX_MESSAGE = 256 * 1024


@dataclass(frozen=True)
class Verdict:
    """The plain key fingerprint of the certificate ssh accepted, or the
    reason it did not (one line)."""

    fingerprint: str | None
    reason: str | None = None


def command(
    address: str,
    port: int,
    user: str | None,
    key_type: str,
    known_hosts: str,
    revoked: str | None,
    timeout: int,
    agent: str = "none",
) -> list[str]:
    """ssh checking the host's certificate and stopping before a login
    (PreferredAuthentications=none: only the "none" method is tried); its
    agent the socket ``agent``, which learns the host key ssh accepted."""
    options = {
        "BatchMode": "yes",
        "StrictHostKeyChecking": "yes",
        "UserKnownHostsFile": known_hosts,
        "GlobalKnownHostsFile": "/dev/null",
        "HostKeyAlgorithms": CERT_ALGORITHMS.get(key_type, key_type),
        "CheckHostIP": "no",
        "UpdateHostKeys": "no",
        "PreferredAuthentications": "none",
        "IdentitiesOnly": "yes",
        "IdentityFile": "none",
        "IdentityAgent": agent,
        "ConnectTimeout": str(timeout),
        "ConnectionAttempts": "1",
        "ControlMaster": "no",
        "ControlPath": "none",
        "ForwardAgent": "no",
    }
    if revoked:
        options["RevokedHostKeys"] = revoked
    argv = ["ssh", "-v", "-F", "/dev/null", "-p", str(port)]
    for key, value in options.items():
        argv += ["-o", f"{key}={value}"]
    if user:
        argv += ["-l", user]
    return argv + ["--", address, "true"]


def accepted(host_key: bytes) -> Verdict:
    """The verdict on the host key ssh accepted (a certificate blob, as ssh
    gave it to its agent): the fingerprint of the plain key it certifies."""
    try:
        kind = paramiko.Message(host_key).get_text()
        key = _CERT_KEYS[kind](data=host_key)
    except (KeyError, paramiko.SSHException, ValueError, TypeError, IndexError) as error:
        return Verdict(None, f"ssh accepted a host key robotfleet cannot read ({error.__class__.__name__}: {error})")
    digest = hashlib.sha256(key.asbytes()).digest()
    return Verdict("SHA256:" + base64.b64encode(digest).decode().rstrip("="))


def refusal(output: str, address: str, known_hosts: str) -> str:
    """Why ssh -v did not accept a certificate, in one line.  A server can
    write into this text too: it only ever explains a refusal."""
    found = _CERTIFICATE.search(output)
    invalid = _INVALID.search(output)
    if invalid:
        why = invalid.group(1).strip()
        if why == "name is not a listed principal":
            why = f"{address} is not one of its principals"
        return f"its host certificate is invalid: {why}{_about(found)}"
    revoked = re.search(r"revoked by file (.*)", output)
    if revoked:
        return f"its host key is revoked by the KRL {revoked.group(1).strip()}{_about(found)}"
    if "is marked as revoked" in output:
        return f"its host key is marked @revoked in {known_hosts}{_about(found)}"
    unreadable = re.search(r"in revoked keys file (.*?): (.*)", output)
    if unreadable:
        return f"cannot read the KRL {unreadable.group(1)}: {unreadable.group(2).strip()}"
    if "no matching host key type found" in output:
        return "it offers no host certificate for that key (sshd_config HostCertificate)"
    if found and "Host key verification failed." in output:
        return (
            f"its host certificate is signed by CA {found.group(4)}, which no @cert-authority line "
            f"of {known_hosts} trusts for it{_about(found)}"
        )
    last = [line for line in output.splitlines() if line.strip() and not line.startswith(("debug", "OpenSSH_"))]
    return f"the certificate check with ssh failed: {last[-1].strip() if last else 'no answer'}"


def _about(found) -> str:
    if not found:
        return ""
    return f" (certificate {found.group(3)!r}, serial {found.group(2)}, valid {found.group(5).strip()})"


class Agent:
    """A stand-in ssh-agent on a socket in a directory only this user can
    enter: it holds no keys, and keeps the host key ssh binds it to."""

    def __init__(self, path: str):
        self.path = path
        self.asked = False  # ssh came: it accepted the host key
        self.host_key: bytes | None = None  # the key it accepted (session-bind, OpenSSH 8.9+)
        self._stop = threading.Event()
        self._socket = socket.socket(socket.AF_UNIX)
        self._socket.bind(path)
        self._socket.listen(4)
        self._socket.settimeout(0.2)
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self):
        while not self._stop.is_set():
            try:
                conn, _ = self._socket.accept()
            except OSError:  # the 0.2 s timeout, or closed
                continue
            with conn:
                conn.settimeout(5)
                try:
                    self._answer(conn)
                except OSError:
                    pass

    def _answer(self, conn):
        while (message := _receive(conn)) is not None:
            self.asked = True
            reply = bytes([_FAILURE])
            if message[:1] == bytes([_REQUEST_IDENTITIES]):
                reply = bytes([_IDENTITIES_ANSWER]) + (0).to_bytes(4, "big")
            elif message[:1] == bytes([_EXTENSION]):
                fields = paramiko.Message(message[1:])
                if fields.get_string() == _SESSION_BIND and self.host_key is None:
                    self.host_key = fields.get_string()
                    reply = bytes([_SUCCESS])
            conn.sendall(len(reply).to_bytes(4, "big") + reply)

    def close(self):
        self._stop.set()
        self._thread.join(timeout=2)
        self._socket.close()


def _receive(conn) -> bytes | None:
    """One agent message (its length, then that many bytes), or None at
    the end or past the size a message of ssh's can have."""
    header = _exactly(conn, 4)
    if header is None or not 0 < int.from_bytes(header, "big") <= _MAX_MESSAGE:
        return None
    return _exactly(conn, int.from_bytes(header, "big"))


def _exactly(conn, size: int) -> bytes | None:
    data = b""
    while len(data) < size:
        chunk = conn.recv(size - len(data))
        if not chunk:
            return None
        data += chunk
    return data


def verify(
    address: str, port: int, user: str | None, key_type: str, known_hosts: str, revoked: str | None, timeout: int
) -> Verdict:
    """Check the host's certificate with OpenSSH's ssh.  The files reach
    ssh through links of plain names: ssh_config expands % tokens in file
    names and splits UserKnownHostsFile at spaces."""
    with tempfile.TemporaryDirectory(prefix="robotfleet-hostcert-") as links:
        names = {os.path.join(links, "known_hosts"): known_hosts}
        if revoked:
            names[os.path.join(links, "revoked.krl")] = revoked
        for link, target in names.items():
            os.symlink(os.path.abspath(target), link)
        try:
            agent = Agent(os.path.join(links, "agent"))
        except OSError as error:
            return Verdict(
                None,
                f"its host certificate cannot be checked: no socket for ssh's agent in {links}: "
                f"{error.strerror or error}",
            )
        argv = command(address, port, user, key_type, *names, *([] if revoked else [None]), timeout, agent.path)
        try:
            proc = subprocess.run(
                argv,
                stdin=subprocess.DEVNULL,
                capture_output=True,
                text=True,
                timeout=timeout * 3 + 5,
                errors="replace",
            )
        except FileNotFoundError:
            return Verdict(None, "its host certificate cannot be checked: OpenSSH's ssh is not installed here")
        except subprocess.TimeoutExpired:
            return Verdict(None, f"the certificate check with ssh took more than {timeout * 3 + 5} s")
        finally:
            agent.close()
    if agent.host_key is not None:
        return accepted(agent.host_key)
    if agent.asked:
        return Verdict(
            None,
            "its host certificate cannot be checked: this machine's ssh is older than OpenSSH 8.9 "
            "(it does not say which host key it accepted)",
        )
    said = proc.stderr
    for link, target in names.items():
        said = said.replace(link, target)
    return Verdict(None, refusal(said, address, known_hosts))
