"""After a power cut: a release left "switching" (the switch was never
verified) is undone at boot, before the unit starts `current`."""

import os

from . import spec as states
from .lock import Busy, Lock
from .system import log, now


def recover(releases):
    """Undo a switch that never finished (power cut or crash between the
    switch and its verdict).  `current` in state "switching" carries where it
    came from; if that release was good, go back to it.  Returns a line for
    the log, or None when there was nothing to undo."""
    rid = releases.pointer("current")
    record = releases.record(rid)
    if not record or record.get("state") != states.SWITCHING:
        return None
    switch = record.get("switch") or {}
    back = switch.get("from")
    if not back or back == rid or releases.state(back) not in states.SETTLED:
        return None  # nothing verified to go back to: run it, the next deploy re-releases it
    releases.point("current", back)
    releases.point("previous", switch.get("previous_before"))
    record.pop("switch", None)
    why = "interrupted before it was verified healthy (power cut, reboot or crash)"
    if switch.get("kind") == "rollback":
        record["state"] = switch.get("prior_state") or states.ACTIVE
        record["rollback_interrupted"] = {"time": now(), "reason": why}
    else:
        record["state"] = states.FAILED
        record["reason"] = why
    releases.write_record(rid, record)
    back_record = releases.record(back) or {}
    back_record["rolled_back_from"] = {"id": rid, "reason": why, "time": now()}
    releases.write_record(back, back_record)
    return "payload: release {} was {}; back on {}".format(rid, why, back)


def start(releases, name):
    """The unit's ExecStart (boot): never run an unverified release blindly.
    When no apply holds the lock, a `current` left "switching" by a power cut
    is undone first; then the current release is brought up."""
    lock = Lock(releases.root, 0, {"by": "boot", "action": "start"})
    try:
        lock.acquire(blocking=False)
    except Busy:
        pass  # an apply or rollback is running and started us: it decides
    except OSError as error:
        log("payload: cannot take the apply lock ({}); starting current as it is".format(error))
    else:
        try:
            recovered = recover(releases)
            if recovered:
                log(recovered)
        finally:
            lock.release()
    compose = os.path.join(releases.root, "current", "compose.yaml")
    os.execvp("docker", ["docker", "compose", "-p", name, "-f", compose, "up", "-d", "--remove-orphans"])
