"""The fingerprint of what a TUF refresh of an unchanged repository reads,
and trust.json's bytes (robotfleet/pull/robot/trust_state.py says what they
stand for).  Apart from trust_state, which needs the release record's
module and datetime: the idle check (robotfleet/pull/robot/idle.py) uses
them with nothing but hashlib, json and the mirror's reader."""

from __future__ import annotations

import hashlib
import json

from robotfleet.pull.robot import fetched

STATE_FORMAT = 1
RECORD_MAX = 16 << 20  # record.py's MAX_BYTES (tests/unit/test_pull_idle_memo.py holds them equal)


def read(source: str, path: str) -> bytes | None:
    """One file of the repository at ``source`` (a directory, or an
    http(s):// base URL), at most the cap of its kind, never through a
    link (robotfleet/pull/robot/fetched.py); None when it is not there (HTTP 404)."""
    limit = fetched.metadata_max(path) if path.startswith("metadata/") else RECORD_MAX
    if source.startswith(("https://", "http://")):
        return fetched.read_url(source.rstrip("/") + "/" + path, limit)
    return fetched.read(source, path, limit)


def fingerprint(source, reads) -> str | None:
    """The sha256 of what a TUF refresh reads of an unchanged repository at
    ``source``: the next root version (absent), timestamp.json and the
    release record's target file (names and contents); None when one
    cannot be read."""
    digest = hashlib.sha256()
    try:
        for path in reads:
            data = read(str(source), path)
            digest.update(f"{path} {hashlib.sha256(data).hexdigest() if data is not None else '-'}\n".encode())
    except (OSError, ValueError):
        return None
    return digest.hexdigest()


def reads_of(root_version: int, release_file: str) -> list[str]:
    return [f"metadata/{root_version + 1}.root.json", "metadata/timestamp.json", release_file]


def trust_bytes(time: str, version: int, release: str | None) -> bytes:
    """trust.json: the last trusted ``time`` (UTC, "...Z"), the highest record ``version`` accepted."""
    state = {"format": STATE_FORMAT, "time": time, "version": version, "release": release}
    return (json.dumps(state, sort_keys=True) + "\n").encode()
