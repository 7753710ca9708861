"""The robot's side of a first report's proof (robotfleet/pull/protocol/enrollment.py):
while the agent holds a bundle's enrollment key, it signs the robot's name,
its own key and its host keys with ``ssh-keygen -Y sign``."""

from __future__ import annotations

import hashlib
import subprocess
from pathlib import Path

from robotfleet.pull.protocol.enrollment import NAMESPACE, SIGNATURE, TIMEOUT, ProofError, message


def sign(private_key: str, text: bytes) -> str:
    """The armored signature of ``text`` by ``private_key`` (ProofError: why not)."""
    try:
        done = subprocess.run(
            ["ssh-keygen", "-q", "-Y", "sign", "-n", NAMESPACE, "-f", private_key],
            input=text,
            capture_output=True,
            timeout=TIMEOUT,
        )
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
