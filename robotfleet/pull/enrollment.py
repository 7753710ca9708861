"""A first report's proof: the bundle's enrollment key signs who the robot says it is.

The robot (the agent, while it holds a bundle's ``enroll_ed25519``) signs
with ``ssh-keygen -Y sign`` (namespace ``robotfleet-enroll``) the text

    robotfleet enrollment 1
    robot robot9
    key ssh-ed25519 AAAA...            its own key for the fleet remote
    host-key ssh-ed25519 AAAA...       each of its SSH host keys, sorted

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
import json
import os
import re
import subprocess
import tempfile
from pathlib import Path

from robotfleet import atomicfile

NAMESPACE = "robotfleet-enroll"
ENV = "ROBOTFLEET_ENROLLMENTS"
SHARED = "enroll+"  # gitolite.SHARED: a shared image's enrollment user, enroll+<rule>+<prefix>
SIGNATURE = re.compile(r"-----BEGIN SSH SIGNATURE-----\n[A-Za-z0-9+/=\n]{1,4000}-----END SSH SIGNATURE-----\n?")
TIMEOUT = 30


class ProofError(Exception):
    """A proof that does not hold (one line)."""


def kept_file(checkout: Path) -> Path:
    """Where the operator keeps enrollment keys' hashes and enrolled robots' keys."""
    return Path(os.environ.get(ENV) or checkout / ".robotfleet" / "enrollments.json")


def key_sha256(public_key: str) -> str:
    """What the operator keeps of a key: the hash of its public half (type and base64)."""
    return hashlib.sha256(" ".join(public_key.split()[:2]).encode()).hexdigest()


def message(robot: str, key: str, host_keys) -> bytes:
    """The text the enrollment key signs: the robot's name, its own key and its host keys."""
    lines = ["robotfleet enrollment 1", f"robot {robot}", f"key {key}"]
    lines += [f"host-key {k}" for k in sorted(host_keys)]
    return ("\n".join(lines) + "\n").encode()


# -- the robot's side ---------------------------------------------------------


def sign(private_key: str, text: bytes) -> str:
    """The armored signature of ``text`` by ``private_key`` (ProofError: why not)."""
    try:
        done = subprocess.run(["ssh-keygen", "-q", "-Y", "sign", "-n", NAMESPACE, "-f", private_key], input=text,
                              capture_output=True, timeout=TIMEOUT)
    except (OSError, subprocess.TimeoutExpired) as error:
        raise ProofError(f"ssh-keygen -Y sign: {error}") from None
    signature = done.stdout.decode(errors="replace")
    if done.returncode or not SIGNATURE.fullmatch(signature):
        lines = [line for line in done.stderr.decode(errors="replace").splitlines() if line.strip()]
        raise ProofError(f"ssh-keygen -Y sign: {lines[-1] if lines else f'exit {done.returncode}'}")
    return signature


def proof(private_key: str, robot: str, key: str | None, host_keys, cache: dict) -> dict | None:
    """The proof for this robot's report: signed again only when the text
    changed and the enrollment key is still here; ``cache`` (the agent's
    state) keeps the last one.  None when there is none to give."""
    if not key:
        return None
    text = message(robot, key, host_keys)
    digest = hashlib.sha256(text).hexdigest()
    last = cache.get("enrollment")
    if isinstance(last, dict) and last.get("message_sha256") == digest and isinstance(last.get("proof"), dict):
        return last["proof"]
    try:
        public = " ".join(Path(f"{private_key}.pub").read_text().split()[:2])
    except OSError:
        return None  # no enrollment key (never had one, or retired): no proof for a new text
    made = {"key": public, "signature": sign(private_key, text)}
    cache["enrollment"] = {"message_sha256": digest, "proof": made}
    return made


# -- the operator's side ------------------------------------------------------


def read_kept(path: Path) -> dict:
    """name -> what the operator keeps for it (an empty dict for a missing or unreadable file)."""
    try:
        found = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return {name: entry for name, entry in found.items() if isinstance(entry, dict)} if isinstance(found, dict) else {}


def enrolled_key(kept: dict, robot: str) -> str | None:
    """The hash of the own key ``robot`` was enrolled with, if any."""
    value = (kept.get(robot) or {}).get("key_sha256")
    return value if isinstance(value, str) else None


def record(path: Path, robot: str, key: str) -> None:
    """Keep the hash of the own key ``robot`` is enrolled with (the file replaced whole)."""
    kept = read_kept(path)
    kept.setdefault(robot, {})["key_sha256"] = key_sha256(key)
    atomicfile.write(path, json.dumps(kept, indent=1, sort_keys=True) + "\n", mode=0o600, make_parents=True)


def issuers(kept: dict, robot: str) -> dict[str, str]:
    """enrollment key hash -> "robot" (its own bundle's) or "shared" (an image whose name rule makes ``robot``)."""
    from robotfleet.pull import gitolite

    found = {}
    for name, entry in kept.items():
        digest = entry.get("enroll_key_sha256")
        if not isinstance(digest, str):
            continue
        if name == robot:
            found[digest] = "robot"
        elif name.startswith(SHARED) and name.count("+") >= 2:
            try:
                if re.fullmatch(gitolite.shared_refex(name), robot):
                    found.setdefault(digest, "shared")
            except (KeyError, re.error):
                continue
    return found


def verify(report: dict, kept: dict, where: str) -> str:
    """Whose enrollment key signed ``report`` ("robot" or "shared"); ProofError: why it proves nothing."""
    given = report.get("enrollment")
    if not given:
        raise ProofError("its report carries no enrollment proof")
    kind = issuers(kept, report["robot"]).get(key_sha256(given["key"]))
    if kind is None:
        raise ProofError(f"its report is signed by an enrollment key {where} does not keep for {report['robot']}")
    text = message(report["robot"], report.get("key") or "", report.get("host_keys") or [])
    with tempfile.TemporaryDirectory(prefix="robotfleet-enroll-") as tmp:
        signers, signature = os.path.join(tmp, "allowed_signers"), os.path.join(tmp, "report.sig")
        Path(signers).write_text(f'enrollment namespaces="{NAMESPACE}" {given["key"]}\n')
        Path(signature).write_text(given["signature"])
        try:
            done = subprocess.run(["ssh-keygen", "-Y", "verify", "-f", signers, "-I", "enrollment", "-n", NAMESPACE,
                                   "-s", signature], input=text, capture_output=True, timeout=TIMEOUT)
        except (OSError, subprocess.TimeoutExpired) as error:
            raise ProofError(f"ssh-keygen -Y verify: {error}") from None
    if done.returncode:
        raise ProofError("its enrollment proof does not verify: the signature is not over what the report says")
    return kind

