"""Reading what a mirror or the git server gave, before TUF has judged it:
the releases checkout (a directory) or a static HTTPS mirror.  A mirror
needs no more trust than a cache, so a file is read only where it is:
never through a symbolic link (one to /dev/zero would read without end,
one to /etc/hostname would read the robot's own file), only a regular file,
and no more than a cap for its kind.

The caps of TUF metadata are python-tuf ngclient's defaults (trust.py
gives them to its Updater, so both readers agree); a target is bounded by
the length its signed targets give (ngclient reads a target's chunks only
up to it).
"""

from __future__ import annotations

import os
import stat

ROOT_MAX = 512000
TIMESTAMP_MAX = 16384
SNAPSHOT_MAX = 2000000
TARGETS_MAX = 5000000
CHUNK = 1 << 16


class NotAFile(OSError):
    """What the mirror has at a path is not a regular file there, or is
    larger than its cap (one line)."""


def open_file(base, path: str) -> int:
    """A read-only descriptor of the regular file ``path`` (relative, with
    /) under the directory ``base``, each directory and the file opened
    without following a link; FileNotFoundError when it is not there,
    NotAFile when a link or anything but a regular file is."""
    parts = [part for part in path.split("/") if part not in ("", ".")]
    if not parts or ".." in parts:
        raise NotAFile(f"{path}: not a path inside {base}")
    at = os.open(base, os.O_RDONLY | os.O_DIRECTORY)
    try:
        for index, part in enumerate(parts):
            last = index == len(parts) - 1
            # O_NONBLOCK: opening a FIFO does not wait for a writer (it is then refused)
            flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | (0 if last else os.O_DIRECTORY)
            try:
                fd = os.open(part, flags, dir_fd=at)
            except OSError as error:
                if isinstance(error, FileNotFoundError):
                    raise
                shown = "/".join(parts[: index + 1])
                if _is_link(at, part):
                    raise NotAFile(
                        f"{base}/{shown}: a symbolic link, not read (a mirror's files are read where they are)"
                    ) from None
                raise NotAFile(f"{base}/{shown}: {'not a directory' if not last else error.strerror}") from None
            os.close(at)
            at = fd
        if not stat.S_ISREG(os.fstat(at).st_mode):
            raise NotAFile(f"{base}/{path}: not a regular file")
        fd, at = at, -1
        return fd
    finally:
        if at >= 0:
            os.close(at)


def _is_link(directory_fd: int, name: str) -> bool:
    try:
        return stat.S_ISLNK(os.lstat(name, dir_fd=directory_fd).st_mode)
    except OSError:
        return False


def chunks(fd: int, limit: int | None = None, where: str = "file"):
    """The content of the open file ``fd`` in chunks (closed at the end);
    NotAFile once more than ``limit`` bytes come."""
    with os.fdopen(fd, "rb", buffering=0) as handle:
        read = 0
        while chunk := handle.read(CHUNK):
            read += len(chunk)
            if limit is not None and read > limit:
                raise NotAFile(f"{where}: larger than {limit} bytes")
            yield chunk
