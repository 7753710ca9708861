"""One deploy at a time on a robot (the apply lock), and the update lock
robot software holds while the robot must not be updated.

The apply lock is root's alone: <payload_dir>/lock/ (0700) holds the lock
file (0600) and owner.json, the holder's note.  flock works on a read-only
descriptor, so a lock any user could open is a lock any user could hold.
The note is removed when the lock is released, and a waiter checks that the
process holding the lock (/proc/locks) is the one the note names: a note
can never name a deploy that has finished, and a holder that is not one of
ours is said to be one.

A holder may record a token in its note (its SHA-256 only: the note is
shown to waiters): a request carrying the same token joins that holder's
run instead of waiting for it (the pull agent holds the lock for a whole
converge run, and the payload's apply inside it must not wait for itself).
A joined run takes the lock over if its holder goes away before it is done.
Anyone else waits or is refused as for any holder."""

import errno
import fcntl
import hashlib
import hmac
import os
import socket
import stat
import threading
import time

from . import durable
from .system import now

DIR = "lock"


class Busy(Exception):
    pass


def token_digest(token):
    return hashlib.sha256(token.encode()).hexdigest()


def _private_dir(path):
    """``path`` as a directory only root can enter; never through a link."""
    os.makedirs(path, mode=0o700, exist_ok=True)
    info = os.lstat(path)
    if not stat.S_ISDIR(info.st_mode) or info.st_uid != os.geteuid():
        raise OSError(errno.EPERM, "not a directory of ours (a link, or another user's)", path)
    if stat.S_IMODE(info.st_mode) != 0o700:
        os.chmod(path, 0o700)


def _holder_pid(fd):
    """The pid holding a flock on the file open as ``fd`` (/proc/locks), or None."""
    info = os.fstat(fd)
    wanted = "{:02x}:{:02x}:{}".format(os.major(info.st_dev), os.minor(info.st_dev), info.st_ino)
    try:
        with open("/proc/locks") as handle:
            for line in handle:
                parts = line.split()
                # "1: FLOCK  ADVISORY  WRITE 1234 08:01:5678 0 EOF" (a waiter's line has "->")
                if len(parts) >= 6 and parts[1] == "FLOCK" and "->" not in parts and parts[5] == wanted:
                    return int(parts[4]) or None
    except (OSError, ValueError):
        pass
    return None


def _command(pid):
    try:
        with open("/proc/{}/cmdline".format(pid), "rb") as handle:
            text = handle.read().replace(b"\0", b" ").decode("utf-8", "replace").strip()
    except OSError:
        return "unknown"
    return "".join(ch for ch in text if ch.isprintable())[:80] or "unknown"


class Lock:
    """The per-robot apply lock: one deploy, rollback or boot start at a time."""

    def __init__(self, root, timeout=0, owner=None):
        self.dir = os.path.join(root, DIR)
        self.path = os.path.join(self.dir, "apply.lock")
        self.owner_path = os.path.join(self.dir, "owner.json")
        self.timeout = timeout
        self.owner = owner or {}
        self.fd = None
        self.joined = False  # part of the run of the holder whose token we carry
        self._guard = threading.Lock()
        self._done = threading.Event()

    def _open(self):
        _private_dir(self.dir)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0), 0o600)
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or info.st_uid != os.geteuid():
            os.close(fd)
            raise OSError(errno.EPERM, "the apply lock is not a regular file of ours", self.path)
        os.fchmod(fd, 0o600)
        return fd

    def acquire(self, blocking=True, on_wait=None, token=None):
        """Take the lock, waiting up to ``timeout`` seconds when ``blocking``;
        ``on_wait(holder)`` is called once if it has to wait.  With the
        ``token`` its holder recorded, join the holder's run at once."""
        fd = self._open()
        deadline = time.time() + self.timeout
        waited = False
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except OSError as error:
                if error.errno not in (errno.EAGAIN, errno.EACCES):
                    os.close(fd)
                    raise
            if token and self._holder_has(fd, token):
                self.fd, self.joined = fd, True
                threading.Thread(target=self._take_over_when_free, daemon=True).start()
                return self
            if not blocking or time.time() >= deadline:
                message = self.busy_message(fd)
                os.close(fd)
                raise Busy(message)
            if on_wait and not waited:
                on_wait(self.holder(fd))
            waited = True
            time.sleep(0.2)
        self.fd = fd
        self.note()
        return self

    def _holder_has(self, fd, token):
        holder = self.holder(fd) or {}
        digest = holder.get("token_sha256")
        return bool(
            not holder.get("foreign") and isinstance(digest, str) and hmac.compare_digest(digest, token_digest(token))
        )

    def _take_over_when_free(self):
        """A joined run whose holder went away (the agent stopped) holds the
        lock itself to its end: no other deploy starts in the middle of it."""
        while not self._done.wait(0.05):
            with self._guard:
                if self._done.is_set():
                    return
                try:
                    fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:
                    continue
                self.joined = False
                self.note()
                return

    def note(self, **more):
        """Write (or amend) the holder's note for waiters; a joined run
        amends its holder's note."""
        self.owner.update(more)
        self.owner.setdefault("since", now())
        note = dict(self.owner, pid=os.getpid())
        if self.joined:
            note = dict(durable.read_json(self.owner_path) or {}, **more)
        try:
            durable.write_json(self.owner_path, note)
        except OSError:
            pass  # the note is a courtesy to waiters; the lock holds without it

    def holder(self, fd=None):
        """Who holds the lock: its note when the process holding the lock is
        the one the note names, else that process marked "foreign"; None
        when nobody holds it."""
        opened = fd is None
        if opened:
            try:
                fd = self._open()
            except OSError:
                return None
        try:
            pid = _holder_pid(fd)
        finally:
            if opened:
                os.close(fd)
        note = durable.read_json(self.owner_path) or {}
        if pid is None:
            return note or None
        if note.get("pid") == pid:
            return note
        return {"foreign": True, "pid": pid, "command": _command(pid)}

    def busy_message(self, fd=None):
        return describe(self.holder(fd)) + "; gave up after {} s (payload_apply_lock_timeout)".format(self.timeout)

    def release(self):
        if self.fd is None:
            return
        with self._guard:
            self._done.set()
            if not self.joined:  # a joined run leaves the lock and its note to its holder
                try:
                    os.unlink(self.owner_path)  # a finished deploy is never named as the holder
                except OSError:
                    pass
                fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()


def describe(holder, host=None):
    """One line naming who holds the apply lock of ``host`` (this robot)."""
    host = host or socket.gethostname()
    if not holder:
        return "the apply lock on {} is held by an unknown process".format(host)
    if holder.get("foreign"):
        return "the apply lock on {} is held by process {} ({}), which is not a deploy of this tool".format(
            host, holder["pid"], holder["command"]
        )
    if holder.get("action") == "start":
        return "{} is recovering from an interrupted release since {}".format(
            host, holder.get("since", "an unknown time")
        )
    return "another deploy is running on {} since {} (by {})".format(
        host, holder.get("since", "an unknown time"), holder.get("by", "unknown")
    )


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
