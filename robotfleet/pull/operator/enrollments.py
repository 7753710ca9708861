"""The operator's side of a first report's proof (robotfleet/pull/protocol/enrollment.py):
which enrollment keys ``robotfleet bundle`` made, for which names, and the
own key each robot was enrolled with (``.robotfleet/enrollments.json``, or
$ROBOTFLEET_ENROLLMENTS); ``pull-enroll`` checks a proof against them with
``ssh-keygen -Y verify``."""

from __future__ import annotations

import json
import os
import re
import subprocess
import tempfile
from pathlib import Path

from robotfleet import atomicfile
from robotfleet.pull.protocol.enrollment import NAMESPACE, TIMEOUT, ProofError, key_sha256, message

ENV = "ROBOTFLEET_ENROLLMENTS"
SHARED = "enroll+"  # gitolite.SHARED: a shared image's enrollment user, enroll+<rule>+<prefix>


def kept_file(checkout: Path) -> Path:
    """Where the operator keeps enrollment keys' hashes and enrolled robots' keys."""
    return Path(os.environ.get(ENV) or checkout / ".robotfleet" / "enrollments.json")


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
    from robotfleet.pull.operator import gitolite

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
            done = subprocess.run(
                ["ssh-keygen", "-Y", "verify", "-f", signers, "-I", "enrollment", "-n", NAMESPACE, "-s", signature],
                input=text,
                capture_output=True,
                timeout=TIMEOUT,
            )
        except (OSError, subprocess.TimeoutExpired) as error:
            raise ProofError(f"ssh-keygen -Y verify: {error}") from None
    if done.returncode:
        raise ProofError("its enrollment proof does not verify: the signature is not over what the report says")
    return kind
