"""Files this machine writes whole or not at all: a temp file of an
unpredictable name created exclusively beside the target (nothing planted
there is followed), fsynced, given its mode, renamed over the target.  A
power cut or a full disk leaves the old file or the new one, never half of
one (rollout state, trust state, metrics for a collector, TUF metadata)."""

from __future__ import annotations

import io
import os

# tempfile's mkstemp, with a name robotfleet/pull/operator/medium.py's TEMP_NAME knows
# (what an interrupted write left on a medium).
_CREATE = os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC


def _temp_beside(path: str) -> tuple[int, str]:
    """A new file of an unpredictable name beside ``path``, 0600: (fd, its path)."""
    directory, name = os.path.split(path)
    for _ in range(100):
        temp = os.path.join(directory, f".{name}.{os.urandom(6).hex()}.tmp")
        try:
            return os.open(temp, _CREATE, 0o600), temp
        except FileExistsError:
            continue
    raise FileExistsError(f"{directory or '.'}: no free temporary name beside {name}")


class replacing:
    """A binary file to write that replaces ``path`` when the ``with`` block
    ends (fsynced, given its mode, renamed over it), or leaves no trace when
    it raises: for what is written as a stream (a copy, an archive).
    ``mode`` None keeps the temp file's 0600; ``make_parents`` creates
    missing directories first; ``keep_mode``: a file already there keeps its
    own mode (``mode`` is a new file's)."""

    def __init__(
        self, path: str | os.PathLike, mode: int | None = None, make_parents: bool = False, keep_mode: bool = False
    ):
        self.path, self.mode = os.fspath(path), mode
        if keep_mode:
            try:
                self.mode = os.stat(self.path).st_mode & 0o7777
            except FileNotFoundError:
                pass
        if make_parents:
            os.makedirs(os.path.dirname(self.path) or ".", exist_ok=True)

    def __enter__(self) -> io.BufferedWriter:
        fd, self.temp = _temp_beside(self.path)
        try:
            self.handle = os.fdopen(fd, "wb")
        except BaseException:
            os.close(fd)
            os.unlink(self.temp)
            raise
        return self.handle

    def __exit__(self, kind, error, trace) -> bool:
        try:
            if kind is None:
                self.handle.flush()
                os.fsync(self.handle.fileno())
            self.handle.close()
            if kind is None:
                if self.mode is not None:
                    os.chmod(self.temp, self.mode)
                os.replace(self.temp, self.path)
        except BaseException:
            self._discard()
            raise
        if kind is not None:
            self._discard()
        return False

    def _discard(self) -> None:
        if not self.handle.closed:
            self.handle.close()
        if os.path.exists(self.temp):
            os.unlink(self.temp)


def write(
    path: str | os.PathLike,
    data: bytes | str,
    mode: int | None = None,
    make_parents: bool = False,
    keep_mode: bool = False,
) -> None:
    """Replace ``path`` with ``data`` (``replacing``'s options)."""
    with replacing(path, mode, make_parents, keep_mode) as handle:
        handle.write(data.encode() if isinstance(data, str) else data)
