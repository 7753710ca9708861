"""`payloadctl hold`: hold the robot's apply lock for as long as a command
runs (the pull agent's converge run of every role), with a token the
command hands to the payloadctl requests that are part of its run.

    payloadctl hold --dir /var/lib/robot-payload --token-file /run/robot-pull/lock-token \\
        [--timeout S] [--by WHO] -- COMMAND ARG...

A new random token is written to the token file (0600, replaced
atomically) and its SHA-256 into the lock's note; COMMAND runs with
PAYLOADCTL_LOCK_TOKEN_FILE naming the file.  An apply whose request carries
the token ("run": {"lock_token": ...}, the payload_lock_token setting) or a
rollback given --lock-token-file joins this run instead of waiting for it;
every other deploy, rollback and the boot's start meet a held lock as they
do for any holder.  The exit status is COMMAND's, or 75 (EX_TEMPFAIL) when
the lock was not free within the timeout; the token file is removed and the
lock released at the end, also when hold is stopped by a signal (which is
passed on to COMMAND)."""

import os
import secrets
import signal
import subprocess

from . import durable
from .lock import Busy, Lock, describe, token_digest
from .releases import Releases
from .system import log

BUSY = 75  # EX_TEMPFAIL: try again later
TOKEN_ENV = "PAYLOADCTL_LOCK_TOKEN_FILE"
DEFAULT_TIMEOUT = 300


def lock_timeout(root, timeout):
    if timeout is not None:
        return timeout
    releases = Releases(root)
    spec = releases.spec(releases.pointer("current"))
    return spec.apply_lock_timeout if spec else DEFAULT_TIMEOUT


def hold(root, token_file, command, timeout=None, by="payloadctl hold"):
    if command and command[0] == "--":
        command = command[1:]
    if not command:
        log("payload: hold needs a command to run (after --)")
        return 2
    token = secrets.token_hex(32)
    lock = Lock(root, lock_timeout(root, timeout), {"by": by, "action": "hold", "token_sha256": token_digest(token)})
    try:
        lock.acquire(on_wait=lambda holder: log("payload: {}; waiting".format(describe(holder))))
    except Busy as busy:
        log("payload: {}".format(busy))
        return BUSY
    child = None
    previous = {}

    def pass_on(signum, frame):
        if child is not None and child.poll() is None:
            child.send_signal(signum)
        raise SystemExit(128 + signum)

    try:
        durable.write_text(token_file, token + "\n")
        for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
            previous[signum] = signal.signal(signum, pass_on)
        child = subprocess.Popen(command, env=dict(os.environ, **{TOKEN_ENV: token_file}))
        return child.wait()
    except OSError as error:
        log("payload: hold could not run {}: {}".format(command[0], error))
        return 127 if child is None else 1
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        try:
            os.unlink(token_file)
        except OSError:
            pass
        lock.release()
