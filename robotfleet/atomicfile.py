"""Files this machine writes whole or not at all: a temp file of an
unpredictable name created exclusively beside the target (nothing planted
there is followed), fsynced, given its mode, renamed over the target.  A
power cut or a full disk leaves the old file or the new one, never half of
one (rollout state, trust state, metrics for a collector, TUF metadata)."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO


@contextlib.contextmanager
def replacing(
    path: str | Path, mode: int | None = None, make_parents: bool = False, keep_mode: bool = False
) -> Iterator[BinaryIO]:
    """A binary file to write that replaces ``path`` when the block ends
    (fsynced, given its mode, renamed over it), or leaves no trace when it
    raises: for what is written as a stream (a copy, an archive).  ``mode``
    None keeps the temp file's 0600; ``make_parents`` creates missing
    directories first; ``keep_mode``: a file already there keeps its own
    mode (``mode`` is a new file's)."""
    path = Path(path)
    if keep_mode:
        try:
            mode = os.stat(path).st_mode & 0o7777
        except FileNotFoundError:
            pass
    directory = path.parent if str(path.parent) else Path(".")
    if make_parents:
        directory.mkdir(parents=True, exist_ok=True)
    fd, temp = tempfile.mkstemp(dir=directory, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        if mode is not None:
            os.chmod(temp, mode)
        os.replace(temp, path)
    except BaseException:
        if os.path.exists(temp):
            os.unlink(temp)
        raise


def write(
    path: str | Path, data: bytes | str, mode: int | None = None, make_parents: bool = False, keep_mode: bool = False
) -> None:
    """Replace ``path`` with ``data`` (``replacing``'s options)."""
    with replacing(path, mode, make_parents, keep_mode) as handle:
        handle.write(data.encode() if isinstance(data, str) else data)
