"""A manual rollback: `current` and `previous` swap, the previous release
comes back with its own spec (no download: it works offline), all or
nothing."""

from . import health
from . import spec as states
from .lock import update_lock_holder
from .recovery import compose_doc
from .results import finish
from .system import now, precise_now


def target_spec(releases, target, current):
    """The spec to bring ``target`` back with: its own, else (a release
    made by an older payloadctl) the current release's with the target's
    compose file (which is on disk)."""
    return releases.spec(target) or releases.spec(current)


def rollback(run_, releases, lock=None):
    """All or nothing: the previous release runs healthy, or `current` and
    `previous` are put back and the release that ran before is started again."""
    root, run_id = releases.root, run_.run_id
    current, previous = releases.pointer("current"), releases.pointer("previous")
    target = releases.record(previous)
    if not previous or target is None:
        return finish(root, False, "payload: no previous release to roll back to", run_id=run_id)
    spec = target_spec(releases, previous, current)
    if spec is None:
        return finish(root, False, "payload: releases {} and {} have no recorded spec (made by an older "
                      "payloadctl); deploy the version you want instead".format(previous, current), run_id=run_id)
    holder = update_lock_holder(spec.lock_file)
    if holder and not run_.force:
        return finish(root, False, "payload: rollback refused, {} is held ({})".format(spec.lock_file, holder),
                      run_id=run_id)
    prior_state = target.get("state")
    target["state"] = states.SWITCHING
    target["switch"] = {"kind": "rollback", "from": current, "previous_before": previous, "prior_state": prior_state}
    releases.write_record(previous, target)
    releases.point("current", previous)
    releases.point("previous", current)
    target["switched"] = precise_now()
    if not target.get("autostart", True):
        target.pop("switch")
        target["state"] = states.STAGED
        target["rolled_back_to"] = now()
        releases.write_record(previous, target)
        return finish(root, True, "payload: rolled back to {} (staged)".format(previous), previous, run_id)
    ok, why = health.start_and_check(spec, False, lock)
    target.pop("switch")
    if ok:
        target["state"] = states.ACTIVE
        target["rolled_back_to"] = now()
        releases.write_record(previous, target)
        health.set_restart_policies(spec.name, health.restart_policies(compose_doc(releases.path(previous, "compose.yaml"))))
        return finish(root, True, "payload: rolled back from {} to {}".format(current, previous), previous, run_id)
    releases.point("current", current)
    releases.point("previous", previous)
    target["state"] = prior_state
    target["rollback_failed"] = {"time": now(), "reason": why}
    releases.write_record(previous, target)
    back_ok, back_why = health.start_and_check(releases.spec(current) or spec, False, lock)
    state = "and it is running" if back_ok else "but it is not healthy either: " + back_why
    return finish(
        root, False,
        "payload: rollback to {} failed ({}); restored {} {}".format(previous, why, current, state),
        current, run_id,
    )
