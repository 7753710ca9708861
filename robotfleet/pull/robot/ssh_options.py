"""The ssh the robot's git runs (``ssh_command``: only its keys, the pinned
host keys, no prompt) and what it offers the git server in its key exchange, cut to
what can be used (robotfleet/pull/robot/transport.py): each list goes
whole in the client's first packet of every session, ~1.2 KB of an idle
check's ~5 KB over SSH (tests/bench/idle_check.py).

- Host key algorithms: those of the pinned keys only (known_hosts under
  HostKeyAlias, StrictHostKeyChecking: no other key could be accepted
  anyway); left to ssh when a line is not a plain pinned key (a
  @cert-authority or @revoked line, an unknown type).
- Ciphers: the AEAD ones (chacha20-poly1305, AES-GCM: OpenSSH since 6.5,
  Go's x/crypto), whose packets need no MAC; the MAC list is the one
  sha2-256 MAC a non-AEAD cipher would need, were one ever chosen.
- The key exchange is ssh's default, post-quantum sntrup761x25519
  included: what it costs in bytes (~2.3 KB a session,
  docs/explanations/pull.md) buys confidentiality against later
  decryption, a choice left to the fleet.
"""

from __future__ import annotations

import shlex

from robotfleet import keepalive as keepalives
from robotfleet.pull.protocol.host_key_alias import HOST_KEY_ALIAS

# (ServerAliveInterval, ServerAliveCountMax): the agent's config gives the host's ssh_keepalive_interval and
# ssh_keepalive_count_max (robotfleet/pull/protocol/agent_files.py); these are their defaults.
KEEPALIVE = keepalives.DEFAULT
silence = keepalives.silence
CIPHERS = "chacha20-poly1305@openssh.com,aes128-gcm@openssh.com,aes256-gcm@openssh.com"
MACS = "hmac-sha2-256-etm@openssh.com"
_ALGORITHMS = {
    "ssh-ed25519": ("ssh-ed25519",),
    "ssh-rsa": ("rsa-sha2-512", "rsa-sha2-256"),
    "ecdsa-sha2-nistp256": ("ecdsa-sha2-nistp256",),
    "ecdsa-sha2-nistp384": ("ecdsa-sha2-nistp384",),
    "ecdsa-sha2-nistp521": ("ecdsa-sha2-nistp521",),
    "sk-ssh-ed25519@openssh.com": ("sk-ssh-ed25519@openssh.com",),
    "sk-ecdsa-sha2-nistp256@openssh.com": ("sk-ecdsa-sha2-nistp256@openssh.com",),
}


def host_key_algorithms(known_hosts: str) -> str | None:
    """The algorithms of the keys pinned in ``known_hosts`` (its text), or
    None when ssh should offer its own (a line it cannot be sure of)."""
    found: list[str] = []
    for line in known_hosts.splitlines():
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if words[0].startswith("@") or len(words) < 3 or words[1] not in _ALGORITHMS:
            return None
        found += [name for name in _ALGORITHMS[words[1]] if name not in found]
    return ",".join(found) or None


def options(known_hosts_path: str) -> list[str]:
    """ssh's -o options for a session with the git server pinned in ``known_hosts_path``."""
    try:
        with open(known_hosts_path) as pinned:
            algorithms = host_key_algorithms(pinned.read(65536))
    except (OSError, UnicodeDecodeError):
        algorithms = None
    chosen = ["-o", f"Ciphers={CIPHERS}", "-o", f"MACs={MACS}"]
    return chosen + (["-o", f"HostKeyAlgorithms={algorithms}"] if algorithms else [])


def ssh_command(keys: list[str], known_hosts: str, log: str, timeout: int, keepalive=KEEPALIVE) -> str:
    """The ssh git runs: only these keys, the pinned host keys, no prompt; a
    server that stops answering given up by ``keepalive`` (interval, count)."""
    parts = [
        "ssh",
        "-F",
        "/dev/null",
        "-o",
        "IdentitiesOnly=yes",
        "-o",
        "BatchMode=yes",
        "-o",
        "StrictHostKeyChecking=yes",
        "-o",
        f"UserKnownHostsFile={known_hosts}",
        "-o",
        f"HostKeyAlias={HOST_KEY_ALIAS}",
        "-o",
        f"ConnectTimeout={min(timeout, 30)}",
        *keepalives.openssh_options(*keepalive),
        "-o",
        "LogLevel=DEBUG1",
        "-E",
        log,
        *options(known_hosts),
    ]
    for key in keys:
        parts += ["-i", key]
    return " ".join(shlex.quote(p) for p in parts)
