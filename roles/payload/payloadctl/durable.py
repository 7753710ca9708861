"""Files that survive a power cut: a power cut must never leave an empty
record, compose file or pointer.  Write a temp file, fsync it, rename it,
then fsync the directory (the rename is only durable once the directory is)."""

import json
import os

# Tests set this to a function called before each durable step with (step,
# path); raising there is a power cut at that step.  Never set on a robot.
before_step = None


def _step(step, path):
    if before_step is not None:
        before_step(step, path)


def fsync_dir(path):
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_bytes(path, data, mode=0o600):
    _step("write", path)
    tmp = path + ".tmp"
    if os.path.lexists(tmp):
        os.unlink(tmp)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), mode)
    try:
        os.fchmod(fd, mode)
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
        os.fsync(fd)
    except BaseException:
        os.close(fd)
        os.unlink(tmp)
        raise
    os.close(fd)
    _step("rename", path)
    os.replace(tmp, path)
    fsync_dir(os.path.dirname(path) or ".")


def symlink(target, link):
    """``link`` pointing at ``target``, switched atomically (a temp link
    renamed over it), durable once its directory is fsynced."""
    _step("link", link)
    tmp = link + ".tmp"
    if os.path.lexists(tmp):
        os.unlink(tmp)
    os.symlink(target, tmp)
    _step("rename", link)
    os.replace(tmp, link)
    fsync_dir(os.path.dirname(link) or ".")


def unlink(path):
    _step("unlink", path)
    os.unlink(path)
    fsync_dir(os.path.dirname(path) or ".")


def write_json(path, data):
    write_bytes(path, (json.dumps(data, indent=2, sort_keys=True) + "\n").encode())


def write_text(path, text):
    write_bytes(path, text.encode())


def read_json(path):
    """The JSON object in ``path``, or None when it is missing or unreadable."""
    try:
        with open(path) as handle:
            data = json.load(handle)
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def make_private_dir(path):
    """A directory only root can read (it may hold payload secrets)."""
    os.makedirs(path, mode=0o700, exist_ok=True)
    os.chmod(path, 0o700)
