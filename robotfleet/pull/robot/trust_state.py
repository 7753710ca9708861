"""What a robot trusts, kept between checks, and the cheap proof that a
check found the same repository as the last one that verified.  Nothing
here imports python-tuf (half of an idle check's CPU was importing it).

    <state>/trust.json      {"format": 1, "time": "...Z", "version": N, "release": "..."}
    <state>/verified.json   {"format": 1, "source": ..., "fingerprint": sha256, "expires": "...Z",
                             "reads": [paths], "record_sha256": ...}
    <state>/verified.release.json   the record that verification accepted

``time`` is the last trusted time and ``version`` the highest record
accepted (robotfleet/pull/robot/verify.py says how they move).  After each full
verification (trust.Client.refresh) ``remember`` keeps a fingerprint of
what a refresh of an unchanged repository reads (the next root version,
absent; timestamp.json; the release record's target file: python-tuf uses
its trusted snapshot and targets while the timestamp names them), the
earliest expiry of everything it verified (each role's metadata and the
record), and the record itself.  A later check that reads the same bytes,
at a trusted time before that expiry, is the same verification with the
same answer: ``recall`` gives the record without running TUF.  Anything
else (one byte changed, a new root, a replayed older branch, time past an
expiry) makes ``recall`` answer None, and the full refresh judges it,
refusals included.
"""

from __future__ import annotations

import datetime
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from robotfleet import atomicfile
from robotfleet.pull.protocol import record as records
from robotfleet.pull.robot import fetched

STATE_FORMAT = 1
EPOCH = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)
VERIFIED = "verified.json"
RECORD_COPY = "verified.release.json"


class Unreadable(ValueError):
    """trust.json cannot be read (one line)."""


@dataclass(frozen=True)
class State:
    """What the robot last trusted (trust.json)."""

    time: datetime.datetime = EPOCH
    version: int = 0
    release: str | None = None


def read_state(state_dir) -> State:
    """The trust state kept in ``state_dir`` (defaults if it has none yet); Unreadable."""
    try:
        raw = json.loads(Path(state_dir, "trust.json").read_text())
        return State(records.parse_time(raw["time"], "trust.json time"), int(raw["version"]), raw.get("release"))
    except FileNotFoundError:
        return State()
    except (ValueError, KeyError, TypeError) as error:
        raise Unreadable(f"{Path(state_dir, 'trust.json')}: unreadable trust state ({error})") from None


def read(source: str, path: str) -> bytes | None:
    """One file of the repository at ``source`` (a directory, or an
    http(s):// base URL), at most the cap of its kind, never through a
    link (robotfleet/pull/robot/fetched.py); None when it is not there (HTTP 404)."""
    limit = fetched.metadata_max(path) if path.startswith("metadata/") else records.MAX_BYTES
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


def write_atomic(path: Path, data: bytes) -> None:
    atomicfile.write(path, data)


def write_state(state_dir, state: State) -> None:
    text = {"format": STATE_FORMAT, "time": records.utc(state.time), "version": state.version, "release": state.release}
    write_atomic(Path(state_dir, "trust.json"), (json.dumps(text, sort_keys=True) + "\n").encode())


def remember(state_dir, source, reads: list[str], record_bytes: bytes, expires: datetime.datetime) -> None:
    """After a full verification of the repository at ``source`` accepted
    ``record_bytes``, valid until ``expires`` (``reads``: reads_of())."""
    state_dir = Path(state_dir)
    found = fingerprint(source, reads)
    if found is None:
        forget(state_dir)
        return
    write_atomic(state_dir / RECORD_COPY, record_bytes)
    write_atomic(
        state_dir / VERIFIED,
        (
            json.dumps(
                {
                    "format": STATE_FORMAT,
                    "source": str(source),
                    "fingerprint": found,
                    "expires": records.utc(expires),
                    "reads": list(reads),
                    "record_sha256": hashlib.sha256(record_bytes).hexdigest(),
                },
                sort_keys=True,
            )
            + "\n"
        ).encode(),
    )


def forget(state_dir) -> None:
    for name in (VERIFIED, RECORD_COPY):
        Path(state_dir, name).unlink(missing_ok=True)


def recall(state_dir, source, now: datetime.datetime, applied: int = 0):
    """(the record, the trusted time) when ``source`` is exactly what the
    last full verification accepted and nothing it verified has expired at
    max(``now``, the last trusted time); then the trusted time moves to that
    moment, as after any successful check.  None: verify in full."""
    state_dir = Path(state_dir)
    try:
        memo = json.loads((state_dir / VERIFIED).read_text())
        if memo.get("format") != STATE_FORMAT:
            return None
        state = read_state(state_dir)
        expires = records.parse_time(memo["expires"], "expires")
        data = (state_dir / RECORD_COPY).read_bytes()
    except (OSError, ValueError, KeyError, TypeError):
        return None
    reference = max(now, state.time)
    if reference >= expires or hashlib.sha256(data).hexdigest() != memo.get("record_sha256"):
        return None
    reads = memo.get("reads")
    if memo.get("source") != str(source) or not isinstance(reads, list) or not all(isinstance(r, str) for r in reads):
        return None
    if fingerprint(source, reads) != memo.get("fingerprint"):
        return None
    try:
        record = records.parse(data)
    except records.RecordError:
        return None
    if record.version < max(applied, state.version):
        return None
    if now > state.time:
        write_state(state_dir, State(now, state.version, state.release))
    return record, reference
