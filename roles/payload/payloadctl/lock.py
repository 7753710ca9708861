"""One deploy at a time on a robot (the apply lock), and the update lock
robot software holds while the robot must not be updated."""

import errno
import fcntl
import os
import socket
import stat
import time

from . import durable
from .system import now


class Busy(Exception):
    pass


class Lock:
    """The per-robot apply lock: one deploy or rollback at a time.  The
    holder writes who it is and since when, so a waiter that gives up can
    say which deploy it waited for."""

    def __init__(self, root, timeout=300, owner=None):
        self.path = os.path.join(root, ".apply.lock")
        self.owner_path = os.path.join(root, ".apply.owner")
        self.timeout = timeout
        self.owner = owner or {}

    def acquire(self, blocking=True):
        self.handle = open(self.path, "a")
        deadline = time.time() + self.timeout
        while True:
            try:
                fcntl.flock(self.handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except OSError as error:
                if error.errno not in (errno.EAGAIN, errno.EACCES):
                    raise
            if not blocking or time.time() >= deadline:
                self.handle.close()
                raise Busy(self.busy_message())
            time.sleep(0.2)
        try:
            durable.write_json(self.owner_path, dict(self.owner, since=now(), pid=os.getpid()))
        except OSError:
            pass  # the owner note is a courtesy to waiters; the lock holds without it
        return self

    def busy_message(self):
        owner = durable.read_json(self.owner_path) or {}
        return "another deploy is running on {} since {} (by {}); gave up after {} s (payload_apply_lock_timeout)".format(
            socket.gethostname(), owner.get("since", "an unknown time"), owner.get("by", "unknown"), self.timeout)

    def release(self):
        fcntl.flock(self.handle, fcntl.LOCK_UN)
        self.handle.close()

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()


def update_lock_holder(path):
    """The update lock's reason, or None when it is not held.  The lock may be
    written by unprivileged robot software: never follow a link, read only a
    regular file, and pass on at most one line of printable text."""
    if not path or not os.path.lexists(path):
        return None
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError as error:
        if error.errno == errno.ELOOP:
            return "the lock is a symbolic link (not read)"
        return "unreadable lock"
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return "the lock is not a regular file (not read)"
        raw = os.read(fd, 4096)
    finally:
        os.close(fd)
    return clean_reason(raw.decode("utf-8", "replace"))


def clean_reason(text, limit=120):
    lines = text.strip().splitlines()
    line = "".join(ch for ch in (lines[0] if lines else "") if ch.isprintable()).strip()
    if len(line) > limit:
        line = line[: limit - 3] + "..."
    return line or "no reason given"
