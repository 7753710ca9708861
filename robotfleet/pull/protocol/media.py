"""A release on removable media (``robotfleet export``): the index of its
image archives, the TUF target ``media.json``.  Pure: building, writing and
reading it; both sides read it.

    {"format": 1, "version": 7,
     "images": {"x86_64": {"reg/ros/payload:1.1": {"digest": "sha256:<the record's pin>",
                                                  "archive": "images/<name>.tar",
                                                  "image": "sha256:<config digest: the image id after docker load>"}}}}

``version`` is the release record's: an index is for one release.  Each
archive is a TUF target too (length and sha256 signed like the code and the
wheels); ``image`` is what the robot checks after ``docker load``, on
either of Docker's image stores (the classic store keeps the image id but
not the registry's digest; the containerd store keeps both).  The machine
is ``uname -m`` as a robot's platform names it (cp313-x86_64 ->
x86_64).  Every problem is one line (MediaError) naming the field.
"""

from __future__ import annotations

import json
import re

from robotfleet.pull.protocol.record import load_json

FORMAT = 1
NAME = "media.json"  # its TUF target path
MAX_BYTES = 4 << 20
REPORTS = "reports"  # <medium>/reports/<robot>.json: reports written back when the remote is out of reach
_DIGEST = re.compile(r"sha256:[0-9a-f]{64}")
_ARCHIVE = re.compile(r"images/[A-Za-z0-9][A-Za-z0-9._-]{0,200}\.tar")
_MACHINE = re.compile(r"x86_64|aarch64|armv7l")


class MediaError(ValueError):
    """An index that cannot be used; the message is one line."""


def archive_path(name: str, machine: str) -> str:
    """The target path of an image's archive for ``machine``, from a name
    unique to the image (its reference and digest, hashed by the caller)."""
    return f"images/{name}-{machine}.tar"


def build(version: int, images: dict[str, dict[str, dict[str, str]]]) -> bytes:
    """The index's bytes (sorted keys: same index, same bytes), checked as a robot reads it."""
    data = (
        json.dumps({"format": FORMAT, "version": version, "images": images}, indent=1, sort_keys=True) + "\n"
    ).encode()
    parse(data)
    return data


def _fail(where: str, expected: str, got) -> MediaError:
    shown = repr(got)
    return MediaError(f"{NAME}: {where}: expected {expected}, got {shown if len(shown) < 80 else shown[:75] + '...'}")


def parse(data: bytes) -> dict:
    """``media.json``'s bytes -> {"version": int, "images": {machine: {ref: {digest, archive, image}}}}."""
    raw = load_json(data, NAME, MAX_BYTES, MediaError)
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        raise _fail(
            "format",
            f"{FORMAT} (a newer robotfleet wrote these media?)",
            raw.get("format") if isinstance(raw, dict) else raw,
        )
    if sorted(raw) != ["format", "images", "version"]:
        raise _fail("the index", "exactly format, version and images", sorted(raw))
    version = raw["version"]
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise _fail("version", "an integer >= 1", version)
    images = raw["images"]
    if not isinstance(images, dict):
        raise _fail("images", "machine -> {image: {digest, archive, image}}", images)
    for machine, entries in images.items():
        if not _MACHINE.fullmatch(machine) or not isinstance(entries, dict):
            raise _fail(f"images.{machine}", "x86_64, aarch64 or armv7l -> {image: {...}}", machine)
        for ref, entry in entries.items():
            where = f"images.{machine}.{ref}"
            if not isinstance(entry, dict) or sorted(entry) != ["archive", "digest", "image"]:
                raise _fail(where, "{digest, archive, image}", entry)
            for key in ("digest", "image"):
                if not isinstance(entry[key], str) or not _DIGEST.fullmatch(entry[key]):
                    raise _fail(f"{where}.{key}", "sha256:<64 hex digits>", entry[key])
            if not isinstance(entry["archive"], str) or not _ARCHIVE.fullmatch(entry["archive"]):
                raise _fail(f"{where}.archive", "a target path images/<name>.tar", entry["archive"])
    return {"version": version, "images": images}
