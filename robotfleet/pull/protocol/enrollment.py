"""A first report's proof: the bundle's enrollment key signs who the robot says it is.

The robot (the agent, while it holds a bundle's ``enroll_ed25519``) signs
with ``ssh-keygen -Y sign`` (namespace ``robotfleet-enroll``) the text

    1  robotfleet enrollment 1          the format and its version
    2  robot robot9
    3  key ssh-ed25519 AAAA...          its own key for the fleet remote
    4+ host-key ssh-ed25519 AAAA...     each of its SSH host keys, sorted

(the numbers are not part of it)
and its reports carry ``"enrollment": {"key": <the enrollment public key>,
"signature": <the armored signature>}`` (the same proof while that text is
the same, after the enrollment key is retired too).  The operator
(``robotfleet pull-enroll``) accepts a proof only from an enrollment key
whose hash ``robotfleet bundle`` kept (``.robotfleet/enrollments.json``, or
$ROBOTFLEET_ENROLLMENTS) for that name, or for a shared image's name rule
matching it, and checks it with ``ssh-keygen -Y verify``.  The same file
keeps the hash of each robot's own key once enrolled: a name reported later
with another key is refused until the operator replaces it.
"""

from __future__ import annotations

import hashlib
import re

NAMESPACE = "robotfleet-enroll"
SIGNATURE = re.compile(r"-----BEGIN SSH SIGNATURE-----\n[A-Za-z0-9+/=\n]{1,4000}-----END SSH SIGNATURE-----\n?")
TIMEOUT = 30


class ProofError(Exception):
    """A proof that does not hold (one line)."""


def key_sha256(public_key: str) -> str:
    """What the operator keeps of a key: the hash of its public half (type and base64)."""
    return hashlib.sha256(" ".join(public_key.split()[:2]).encode()).hexdigest()


def message(robot: str, key: str, host_keys) -> bytes:
    """The text the enrollment key signs: the robot's name, its own key and its host keys."""
    lines = ["robotfleet enrollment 1", f"robot {robot}", f"key {key}"]
    lines += [f"host-key {k}" for k in sorted(host_keys)]
    return ("\n".join(lines) + "\n").encode()
