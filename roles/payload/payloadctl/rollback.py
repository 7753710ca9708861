"""A manual rollback: `current` and `previous` swap, the previous release
comes back with its own spec (no download: it works offline), all or
nothing (lifecycle.Life.roll_back, keep, stage, fail)."""

from . import health, results, start
from .lock import update_lock_holder
from .recovery import compose_doc
from .releases import restart_policies


def target_spec(releases, target, current):
    """The spec to bring ``target`` back with: its own, else (a release
    made by an older payloadctl) the current release's with the target's
    compose file (which is on disk)."""
    return releases.spec(target) or releases.spec(current)


def rollback(run_, life, lock=None):
    """All or nothing: the previous release runs healthy, or `current` and
    `previous` are put back and the release that ran before is started again."""
    root = life.root
    current, previous = life.current(), life.previous()

    def finish(outcome, message, target=None, reason=None):
        return results.finish(root, "rollback", outcome, message, run_, target, reason)

    if not previous or life.record(previous) is None or current is None:
        return finish(
            results.REFUSED,
            "payload: no previous release to roll back to",
            reason="no previous release to roll back to",
        )
    spec = target_spec(life.releases, previous, current)
    if spec is None:
        why = (
            "releases {} and {} have no recorded spec (made by an older payloadctl); deploy the version you "
            "want instead".format(previous, current)
        )
        return finish(results.REFUSED, "payload: " + why, reason=why)
    holder = update_lock_holder(spec.lock_file)
    if holder and not run_.force:
        why = "rollback refused, {} is held ({})".format(spec.lock_file, holder)
        return finish(results.REFUSED, "payload: " + why, reason=why)
    target = life.roll_back()
    if target.autostart is False:
        life.stage(previous)
        return finish(results.STAGED, "payload: rolled back to {} (staged)".format(previous), previous)
    ok, why = start.start_and_check(life.releases, spec, False, lock)
    if ok:
        life.keep(previous)
        health.set_restart_policies(
            spec.name, restart_policies(compose_doc(life.releases.path(previous, "compose.yaml")))
        )
        return finish(results.APPLIED, "payload: rolled back from {} to {}".format(current, previous), previous)
    life.fail(previous, why)
    back_ok, back_why = start.start_and_check(life.releases, life.releases.spec(current) or spec, False, lock)
    state = "and it is running" if back_ok else "but it is not healthy either: " + back_why
    return finish(
        results.ROLLED_BACK,
        "payload: rollback to {} failed ({}); restored {} {}".format(previous, why, current, state),
        previous,
        why,
    )
