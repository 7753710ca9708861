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
"""

from __future__ import annotations

import os
import re
import subprocess
import tempfile
from dataclasses import dataclass

# The certificate algorithms for each plain key type paramiko may be offered.
CERT_ALGORITHMS = {
    "ssh-ed25519": "ssh-ed25519-cert-v01@openssh.com",
    "ecdsa-sha2-nistp256": "ecdsa-sha2-nistp256-cert-v01@openssh.com",
    "ecdsa-sha2-nistp384": "ecdsa-sha2-nistp384-cert-v01@openssh.com",
    "ecdsa-sha2-nistp521": "ecdsa-sha2-nistp521-cert-v01@openssh.com",
    "ssh-rsa": "rsa-sha2-512-cert-v01@openssh.com,rsa-sha2-256-cert-v01@openssh.com",
}
_CERTIFICATE = re.compile(r'Server host certificate: \S+ (SHA256:[A-Za-z0-9+/]+),? serial (\d+) ID "(.*)" CA \S+ '
                          r"(SHA256:[A-Za-z0-9+/]+) valid (.*)$", re.M)
_ACCEPTED = ("Authentications that can continue", "Permission denied", "SSH2_MSG_SERVICE_ACCEPT received")


@dataclass(frozen=True)
class Verdict:
    """The plain key fingerprint of the certificate ssh accepted, or the
    reason it did not (one line)."""

    fingerprint: str | None
    reason: str | None = None


def command(address: str, port: int, user: str | None, key_type: str, known_hosts: str, revoked: str | None,
            timeout: int) -> list[str]:
    """ssh checking the host's certificate and stopping before a login
    (PreferredAuthentications=none: only the "none" method is tried)."""
    options = {
        "BatchMode": "yes", "StrictHostKeyChecking": "yes", "UserKnownHostsFile": known_hosts,
        "GlobalKnownHostsFile": "/dev/null", "HostKeyAlgorithms": CERT_ALGORITHMS.get(key_type, key_type),
        "CheckHostIP": "no", "UpdateHostKeys": "no", "PreferredAuthentications": "none",
        "IdentitiesOnly": "yes", "IdentityFile": "none", "ConnectTimeout": str(timeout),
        "ConnectionAttempts": "1", "ControlMaster": "no", "ControlPath": "none", "ForwardAgent": "no",
    }
    if revoked:
        options["RevokedHostKeys"] = revoked
    argv = ["ssh", "-v", "-F", "/dev/null", "-p", str(port)]
    for key, value in options.items():
        argv += ["-o", f"{key}={value}"]
    if user:
        argv += ["-l", user]
    return argv + ["--", address, "true"]


def judge(output: str, address: str, known_hosts: str) -> Verdict:
    """What ssh -v said: the accepted certificate's key, or why not."""
    found = _CERTIFICATE.search(output)
    if "Host key verification failed." not in output and found and any(m in output for m in _ACCEPTED):
        return Verdict(found.group(1))
    invalid = re.search(r"Certificate invalid: (.*)", output)
    if invalid:
        why = invalid.group(1).strip()
        if why == "name is not a listed principal":
            why = f"{address} is not one of its principals"
        return Verdict(None, f"its host certificate is invalid: {why}{_about(found)}")
    revoked = re.search(r"revoked by file (.*)", output)
    if revoked:
        return Verdict(None, f"its host key is revoked by the KRL {revoked.group(1).strip()}{_about(found)}")
    if "is marked as revoked" in output:
        return Verdict(None, f"its host key is marked @revoked in {known_hosts}{_about(found)}")
    unreadable = re.search(r"in revoked keys file (.*?): (.*)", output)
    if unreadable:
        return Verdict(None, f"cannot read the KRL {unreadable.group(1)}: {unreadable.group(2).strip()}")
    if found:
        return Verdict(None, f"its host certificate is signed by CA {found.group(4)}, which no @cert-authority line "
                             f"of {known_hosts} trusts for it{_about(found)}")
    if "no matching host key type found" in output:
        return Verdict(None, "it offers no host certificate for that key (sshd_config HostCertificate)")
    last = [line for line in output.splitlines() if line.strip() and not line.startswith(("debug", "OpenSSH_"))]
    return Verdict(None, f"the certificate check with ssh failed: {last[-1].strip() if last else 'no answer'}")


def _about(found) -> str:
    if not found:
        return ""
    return f" (certificate {found.group(3)!r}, serial {found.group(2)}, valid {found.group(5).strip()})"


def verify(address: str, port: int, user: str | None, key_type: str, known_hosts: str, revoked: str | None,
           timeout: int) -> Verdict:
    """Check the host's certificate with OpenSSH's ssh.  The files reach
    ssh through links of plain names: ssh_config expands % tokens in file
    names and splits UserKnownHostsFile at spaces."""
    with tempfile.TemporaryDirectory(prefix="robotfleet-hostcert-") as links:
        names = {os.path.join(links, "known_hosts"): known_hosts}
        if revoked:
            names[os.path.join(links, "revoked.krl")] = revoked
        for link, target in names.items():
            os.symlink(os.path.abspath(target), link)
        argv = command(address, port, user, key_type, *names, *([] if revoked else [None]), timeout)
        try:
            proc = subprocess.run(argv, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                                  timeout=timeout * 3 + 5, errors="replace")
        except FileNotFoundError:
            return Verdict(None, "its host certificate cannot be checked: OpenSSH's ssh is not installed here")
        except subprocess.TimeoutExpired:
            return Verdict(None, f"the certificate check with ssh took more than {timeout * 3 + 5} s")
    said = proc.stderr
    for link, target in names.items():
        said = said.replace(link, target)
    return judge(said, address, known_hosts)
