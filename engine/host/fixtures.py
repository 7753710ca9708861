"""Test fixtures shared by the roles' fixtures.py: host state as the snapshot reads it."""

from engine.host.operations import sha256
from engine.host.snapshot import FileState


def file_state(text: str, mode: str = "644", user: str = "root", group: str = "root") -> FileState:
    """A regular file holding ``text``."""
    return FileState("file", sha256(text.encode()), mode, user, group)
