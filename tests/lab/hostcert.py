"""Host certificates for a lab host, as docs/guides/host-certificates.md tells an
operator to make them: a host CA (ssh-keygen), the host's ed25519 key signed
with principals and a validity period, the certificate installed with a
HostCertificate line and sshd reloaded.  Nothing here runs at `up`: only
the tests that need a signed host call it (tests/e2e/test_hostcerts.py).
"""

from __future__ import annotations

import subprocess
from pathlib import Path

from tests.lab import state as lab_state

HOST_KEY = "/etc/ssh/ssh_host_ed25519_key.pub"
CERTIFICATE = "/etc/ssh/ssh_host_ed25519_key-cert.pub"
DROP_IN = "/etc/ssh/sshd_config.d/robotfleet-host-certificate.conf"


def make_ca(directory: Path, name: str = "fleet-host-ca") -> Path:
    """A host CA's private key (its public half beside it, ``.pub``)."""
    key = directory / name
    subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", name, "-f", str(key)], check=True)
    return key


def host_key(prefix: str, host: str) -> str:
    """The host's ed25519 public key line."""
    code, out = lab_state.exec_in(prefix, host, ["cat", HOST_KEY])
    if code != 0:
        raise lab_state.LabError(f"{host}: cannot read {HOST_KEY}: {out.strip()}")
    return out.strip()


def sign(
    ca: Path,
    public_key: str,
    directory: Path,
    identity: str,
    principals: list[str],
    validity: str = "-5m:+1h",
    serial: int = 1,
) -> Path:
    """A host certificate of ``public_key`` (ssh-keygen -s -h), written in
    ``directory``; its path."""
    directory.mkdir(parents=True, exist_ok=True)
    plain = directory / f"{identity}-{serial}.pub"
    plain.write_text(public_key + "\n")
    subprocess.run(
        [
            "ssh-keygen",
            "-q",
            "-s",
            str(ca),
            "-h",
            "-I",
            identity,
            "-n",
            ",".join(principals),
            "-V",
            validity,
            "-z",
            str(serial),
            str(plain),
        ],
        check=True,
        capture_output=True,
    )
    return directory / f"{identity}-{serial}-cert.pub"


def install(prefix: str, host: str, certificate: Path) -> None:
    """Put the certificate on the host and make its sshd present it."""
    text = certificate.read_text().strip()
    script = (
        f"printf '%s\\n' '{text}' > {CERTIFICATE} && chmod 644 {CERTIFICATE} && "
        f"echo 'HostCertificate {CERTIFICATE}' > {DROP_IN} && sshd -t && systemctl reload ssh"
    )
    code, out = lab_state.exec_in(prefix, host, script)
    if code != 0:
        raise lab_state.LabError(f"{host}: installing the host certificate failed: {out.strip()}")


def remove(prefix: str, host: str) -> None:
    lab_state.exec_in(prefix, host, f"rm -f {CERTIFICATE} {DROP_IN} && systemctl reload ssh")


def revoke(key_or_certificate: Path, krl: Path) -> Path:
    """A KRL (ssh-keygen -k) revoking the given key or certificate."""
    subprocess.run(["ssh-keygen", "-q", "-k", "-f", str(krl), str(key_or_certificate)], check=True, capture_output=True)
    return krl
