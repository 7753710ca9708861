"""Bring `current` up and wait for its verdict.

While the payload's unit runs, `current` is brought up here, in this
process, with what the unit's reload runs (recovery.up): the update and the
way back after a failed release pay no systemctl round trip and no second
payloadctl, so the old release is running again as soon as the tool has
Docker's verdict.  Otherwise (the unit is stopped, or it changed and must
restart) the unit is started or restarted, as the boot starts it."""

import subprocess
import time

from . import health, recovery
from .system import Failure, run

UNIT_BUSY = ("activating", "deactivating", "reloading")
UNIT_SETTLE = 120  # seconds to wait for a start in progress (the boot's) to finish
POLL = 0.5


def settled_state(unit):
    """The unit's ActiveState once no start is in progress: a start in
    progress (the boot's compose up) is never cut short by a restart or a
    second compose up: that leaves a half-recreated container behind."""
    deadline = time.time() + UNIT_SETTLE
    while True:
        state = run(["systemctl", "show", "-p", "ActiveState", "--value", unit], check=False, timeout=60).stdout.strip()
        if state not in UNIT_BUSY or time.time() >= deadline:
            return state
        time.sleep(POLL)


def start_release(releases, name, restart, lock=None):
    """Run `current`: here while the unit is active (unless it must
    restart), else through the unit.  ``lock`` (the apply lock this run
    holds) notes that the unit's start is ours, so that start runs without
    waiting for the lock (recovery.start)."""
    unit = name + ".service"
    if settled_state(unit) == "active" and not restart:
        recovery.up(releases, name, timeout=600)
        return
    if lock is not None:
        lock.note(starts_unit=True)
    try:
        run(["systemctl", "restart", unit], timeout=600)
    finally:
        if lock is not None:
            lock.note(starts_unit=False)


def start_and_check(releases, spec, restart, lock=None):
    """Bring `current` up and wait for it: (healthy?, why not)."""
    since = time.time()  # Docker's events from here on wake the health wait
    try:
        start_release(releases, spec.name, restart, lock)
        return health.wait_healthy(spec.name, spec.health_timeout, spec.stable_seconds, since=since)
    except Failure as error:
        return False, str(error)
    except subprocess.TimeoutExpired as error:
        return False, "{} did not finish within {} s".format(" ".join(error.cmd[:3]), error.timeout)
