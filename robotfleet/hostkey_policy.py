"""How the fleet's connector checks a host's key (ssh_strict_host_key_checking
yes or accept-new): the fleet's known_hosts as robotfleet/hostkeys.py reads it
(paramiko gives up on a file at its first ``@cert-authority`` line), plain
keys as paramiko would, ``@revoked`` keys refused, a host known only through
an ``@cert-authority`` line has its certificate checked by OpenSSH
(robotfleet/hostcerts.py), never trusted on first use, and accept-new writes
a host's key to known_hosts once (pyinfra's policy appends it at each
connection of the run).  What a refusal says is the connector's
(robotfleet/connect.py)."""

from __future__ import annotations

import os
from dataclasses import dataclass

from paramiko import MissingHostKeyPolicy, SSHException
from paramiko import SSHClient as ParamikoClient
from pyinfra.connectors.sshuserclient import client as sshuserclient

from robotfleet import hostcerts, hostkeys


class UnknownHostKey(SSHException):
    def __init__(self, entry: str, key):
        super().__init__(f"no host key for {entry}")
        self.entry, self.key = entry, key


class RefusedHostKey(SSHException):
    """A host key or certificate refused; ``reason`` says why in words."""

    def __init__(self, entry: str, reason: str):
        super().__init__(reason)
        self.entry, self.reason = entry, reason


@dataclass(frozen=True)
class HostKeyCheck:
    """How a host's key is checked (ssh_strict_host_key_checking yes or
    accept-new): the fleet's known_hosts, its KRL, and for the certificate
    check with OpenSSH the login name and the timeout."""

    known_hosts: str
    revoked: str | None
    user: str | None
    timeout: int
    accept_new: bool = False


def address_of(entry: str) -> tuple[str, int]:
    """(address, port) of a known_hosts entry (``[address]:port`` or ``address``)."""
    if entry.startswith("[") and "]:" in entry:
        address, _, port = entry[1:].rpartition("]:")
        return address, int(port)
    return entry, 22


class FleetPolicy(MissingHostKeyPolicy):
    """A host paramiko found no plain key for: a revoked key is refused; a
    certificate an ``@cert-authority`` line covers is checked by OpenSSH;
    else the host is unknown (refused, or trusted on first use with accept-new)."""

    def __init__(self, check: HostKeyCheck):
        self.check = check

    def missing_host_key(self, client, hostname, key):
        known = hostkeys.cached(self.check.known_hosts)
        if known.revoked_key(key):
            raise RefusedHostKey(
                hostname,
                f"host key REVOKED: {key.get_name()} {hostkeys.fingerprint(key)} is marked "
                f"@revoked in {self.check.known_hosts}; refused",
            )
        address, port = address_of(hostname)
        if known.authorities_for(hostname) or known.authorities_for(address):
            self.certified(hostname, address, port, key)
            client._host_keys.add(hostname, key.get_name(), key)  # for this run only, never written
            return
        self.unknown(client, hostname, key)

    def certified(self, hostname: str, address: str, port: int, key) -> None:
        if self.check.revoked and not os.path.isfile(self.check.revoked):
            raise RefusedHostKey(
                hostname, f"host certificate refused: the KRL {self.check.revoked} (ssh_revoked_host_keys) is missing"
            )
        verdict = hostcerts.verify(
            address,
            port,
            self.check.user,
            key.get_name(),
            self.check.known_hosts,
            self.check.revoked,
            self.check.timeout,
        )
        offered = hostkeys.fingerprint(key)
        if verdict.fingerprint is None:
            raise RefusedHostKey(hostname, f"host certificate refused: {verdict.reason}")
        if verdict.fingerprint != offered:
            raise RefusedHostKey(
                hostname,
                f"host certificate refused: it certifies {verdict.fingerprint}, but this "
                f"connection was offered {key.get_name()} {offered}",
            )

    def unknown(self, client, hostname, key):
        if not self.check.accept_new:
            raise UnknownHostKey(hostname, key)
        # Trust on first use, written once: to known_hosts (unless a line for
        # this host and key is already there) and to the run's loaded keys.
        client._host_keys.add(hostname, key.get_name(), key)
        with sshuserclient.HOST_KEYS_LOCK:
            hostkeys.append(self.check.known_hosts, hostname, key)


class FleetKnownHosts(ParamikoClient):
    """Runs between pyinfra's SSHClient.connect and paramiko's (its place in
    Client's MRO): under the fleet's policy, paramiko matches the plain keys
    robotfleet/hostkeys.py read (revoked ones left out) and asks the policy
    about any other key."""

    def connect(self, hostname, **kwargs):
        if isinstance(self._policy, FleetPolicy):
            self._host_keys = hostkeys.cached(self._policy.check.known_hosts).usable()
            self._host_keys_filename = self._policy.check.known_hosts
        return super().connect(hostname, **kwargs)
