"""A robot with an OpenSSH host certificate, on 127.0.0.1, with no sshd:
a host CA and certificates made by ssh-keygen, presented by paramiko's
server side (tests/integration/sshserver.py) beside the plain key, so that
OpenSSH's ssh (which asks for the certificate type only) checks a real
certificate and paramiko (which asks for the plain type) logs in."""

from __future__ import annotations

import base64
import subprocess
from pathlib import Path

import paramiko

from tests.integration import sshserver


class CertifiedKey:
    """A host key as a server presents it under its certificate: the
    certificate's blob, signatures made by the plain key."""

    def __init__(self, key: paramiko.PKey, certificate: Path):
        kind, blob = certificate.read_text().split()[:2]
        self.key, self.kind, self.blob = key, kind, base64.b64decode(blob)

    def get_name(self) -> str:
        return self.kind

    def asbytes(self) -> bytes:
        return self.blob

    def can_sign(self) -> bool:
        return True

    def sign_ssh_data(self, data, algorithm=None):
        return self.key.sign_ssh_data(data, algorithm)


class HostCA:
    """A host CA in ``directory`` (ssh-keygen's files)."""

    def __init__(self, directory: Path, name: str = "host-ca"):
        self.directory, self.path = directory, directory / name
        keygen("-t", "ed25519", "-N", "", "-C", name, "-f", str(self.path))

    def line(self, patterns: str) -> str:
        return f"@cert-authority {patterns} {(self.path.parent / (self.path.name + '.pub')).read_text()}"

    def host_key(self, name: str, principals: str = "127.0.0.1", validity: str = "-5m:+1d", serial: int = 3) -> Path:
        """A new ed25519 host key, signed: its certificate's path."""
        private = self.directory / name
        keygen("-t", "ed25519", "-N", "", "-f", str(private))
        keygen(
            "-s",
            str(self.path),
            "-h",
            "-I",
            name,
            "-n",
            principals,
            "-V",
            validity,
            "-z",
            str(serial),
            str(private) + ".pub",
        )
        return self.directory / f"{name}-cert.pub"


def keygen(*args: str) -> None:
    subprocess.run(["ssh-keygen", "-q", *args], check=True, capture_output=True)


def private_key(certificate: Path) -> paramiko.Ed25519Key:
    return paramiko.Ed25519Key.from_private_key_file(str(certificate).removesuffix("-cert.pub"))


class CertifiedServer(sshserver.Listener):
    """An SSH server presenting ``certificate`` to whoever asks for its
    type and the plain key ``offered`` (by default the certified one) to
    whoever asks for a plain key; it accepts ``client_key``."""

    def __init__(self, certificate: Path, client_key=None, offered: paramiko.PKey | None = None, greeting=b""):
        self.certified = CertifiedKey(private_key(certificate), certificate)
        super().__init__(host_key=offered or self.certified.key, client_key=client_key, greeting=greeting)

    def _ssh(self, conn):
        transport = paramiko.Transport(conn)
        self.open.append(transport)
        transport.add_server_key(self.host_key)
        transport.add_server_key(self.certified)
        try:
            transport.start_server(server=sshserver._Server(self.client_key, self.answer, self.global_requests))
        except (paramiko.SSHException, EOFError, OSError):
            return
