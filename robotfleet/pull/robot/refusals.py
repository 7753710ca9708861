"""Why a robot refuses a release, its metadata or a target: one of REASONS
(machine-readable, in reports) and one line (Refused), python-tuf's
exceptions sorted into them, and for metadata short of its signatures
whether it was unsigned, signed by an unknown key or changed.  The refresh
that meets them is robotfleet/pull/robot/verify.py's."""

from __future__ import annotations

from pathlib import Path

from tuf.api import exceptions
from tuf.api.metadata import Metadata, Root

# Why a refresh or a download was refused (machine-readable, in reports).
UNSIGNED = "unsigned"  # metadata with no signature
UNKNOWN_KEY = "unknown-key"  # signed, but not by a key the trusted root names for that role
TAMPERED = "tampered"  # a signature by a trusted key that does not verify; a hash or length that differs
ROLLBACK = "rollback"  # a version below one already trusted or applied
EXPIRED = "expired"  # expired metadata or record (a freeze: the newest release withheld)
MALFORMED = "malformed"  # not TUF metadata or not a release record
UNAVAILABLE = "unavailable"  # could not be fetched (no file, no answer): nothing was judged
REASONS = (UNSIGNED, UNKNOWN_KEY, TAMPERED, ROLLBACK, EXPIRED, MALFORMED, UNAVAILABLE)


class Refused(Exception):
    """A release (or its metadata, or a target) the robot does not accept.
    ``reason``: one of REASONS; ``str()``: one line for the journal and the report."""

    def __init__(self, reason: str, line: str):
        super().__init__(line)
        self.reason = reason
        self.line = line


def first_line(error: BaseException) -> str:
    text = str(error).strip() or type(error).__name__
    return text.splitlines()[0][:300]


def unsigned_reason(data: bytes | None, metadata_dir: Path) -> tuple[str, str]:
    """For metadata whose signatures do not meet its threshold: unsigned,
    unknown key or tampered, and the role's name."""
    try:
        md = Metadata.from_bytes(data or b"")
        role = md.signed.type
        trusted = Metadata[Root].from_file(str(metadata_dir / "root.json")).signed
        keyids = set(trusted.roles[role].keyids)
    except Exception:  # unreadable here means the refusal stays "tampered"
        return TAMPERED, "metadata"
    if not md.signatures:
        return UNSIGNED, role
    if not keyids & set(md.signatures):
        return UNKNOWN_KEY, role
    return TAMPERED, role


WORDS = {
    UNSIGNED: "not signed",
    UNKNOWN_KEY: "signed by a key the robot does not trust",
    TAMPERED: "changed after it was signed",
}


def classified(error: BaseException) -> Refused:
    """python-tuf's exception -> Refused with one of REASONS."""
    line = first_line(error)
    if isinstance(error, exceptions.LengthOrHashMismatchError):
        return Refused(TAMPERED, f"does not match what was signed ({line})")
    if isinstance(error, exceptions.DownloadLengthMismatchError):
        return Refused(TAMPERED, f"longer than what was signed ({line})")
    if isinstance(error, exceptions.BadVersionNumberError):
        return Refused(ROLLBACK, f"older than what the robot trusts: refused as a rollback ({line})")
    if isinstance(error, exceptions.ExpiredMetadataError):
        return Refused(EXPIRED, f"expired: refused as a freeze ({line})")
    if isinstance(error, exceptions.DownloadError):
        cause = error.__cause__ or error.__context__
        return Refused(UNAVAILABLE, f"could not be fetched ({line}{': ' + first_line(cause) if cause else ''})")
    if isinstance(error, OSError):
        return Refused(UNAVAILABLE, f"could not be read or written ({line})")
    return Refused(MALFORMED, f"not valid TUF metadata ({line})")
