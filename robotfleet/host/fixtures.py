"""Test fixtures shared by the roles' fixtures.py: host state as the snapshot reads it."""

from robotfleet.host.operations import sha256
from robotfleet.host.snapshot import FileState


def file_state(content: str | bytes, mode: str = "644", user: str = "root", group: str = "root") -> FileState:
    """A regular file holding ``content``."""
    return FileState("file", sha256(content.encode() if isinstance(content, str) else content), mode, user, group)
