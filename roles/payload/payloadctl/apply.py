"""A release: download first, switch, wait healthy, keep it or switch back.

`apply` does it all at once.  A pull robot can split it at the prepared
state: `prepare` (before its maintenance window: the images present, the
release written and checked, nothing that runs touched) and `switch`
(in the window: the rest of an apply, from the switch on).

Runs holding the robot's apply lock (cli.locked); every change of a record
or a pointer is a transition of lifecycle.Life, so a power cut at any point
is undone at boot (recovery.py) or by the next deploy."""

import shutil

from . import health, images, platforms, results, start, takeover
from .lifecycle import PREPARED, SETTLED, Record
from .lock import update_lock_holder
from .releases import compose_yaml, for_engine, gc, release_compose, restart_policies
from .system import Failure, Refusal, now, run


def already_current(spec, run_, life, old):
    """An apply that waited for another one (two deploys at once, or a rerun
    after a dropped SSH link) may find the work done."""
    running = life.record(old) if old else None
    return bool(
        running
        and not run_.restart
        and running.spec_hash == spec.spec_hash
        and running.state in SETTLED
        and (not spec.autostart or health.containers_up(spec.name))
    )


def obtain_images(spec, robot):
    """Every service's image present, built for this robot's platform, and
    pinned: (compose with pinned images, {ref: {id, pinned, platform}}).
    An image for another platform is refused here, before the switch."""
    doc = {**spec.compose, "services": {k: dict(v) for k, v in spec.compose["services"].items()}}
    found = {}
    arch, version = images.engine()
    for service in doc["services"].values():
        ref = service["image"]
        info = images.obtain(ref, spec.delivery, spec.pull_timeout, service.get("platform"))
        images.check_platform(ref, info, robot, arch)
        service["image"] = images.pinned(ref, info)
        found[ref] = {"id": info["id"], "pinned": service["image"], "platform": platforms.text(info["platform"])}
    return for_engine(doc, version), found


def check_compose(name, path):
    """`docker compose config -q` on the robot before the release switches;
    None when it accepts the file, else why not."""
    proc = run(["docker", "compose", "-p", name, "-f", path, "config", "-q"], check=False)
    if proc.returncode == 0:
        return None
    missing = compose_missing()
    if missing:
        return missing
    why = (proc.stderr or proc.stdout).strip().splitlines() or ["no output"]
    return "docker compose config refused the release (nothing switched): {}".format(why[-1][-300:])


def compose_missing():
    """One line when this robot has no Compose v2 (`docker compose version` fails: no plugin, or only the
    old docker-compose v1), which Docker would answer with its usage text; None when it has it."""
    if run(["docker", "compose", "version"], check=False).returncode == 0:
        return None
    v1 = (
        " (only the old docker-compose v1 is installed, which payloadctl does not use)"
        if shutil.which("docker-compose")
        else ""
    )
    return (
        "Docker Compose v2 is missing on this robot: `docker compose version` fails{}; nothing switched. "
        "The docker role installs it (docker-compose-plugin in docker_packages, or the distribution's compose "
        "v2 with docker_source: distro): deploy with the docker role in ROLES, then again.".format(v1)
    )


def _finisher(spec, run_, action):
    def finish(outcome, message, target=None, reason=None, taken=()):
        return results.finish(spec.dir, action, outcome, message, run_, target, reason, taken)

    return finish


def _held(spec, run_, old, finish):
    """The refusal while the update lock is held (None: go on)."""
    holder = update_lock_holder(spec.lock_file)
    if holder and old and not run_.force:
        why = "update refused, {} is held ({})".format(spec.lock_file, holder)
        return finish(
            results.REFUSED, "payload: {}; run again with --data payload_force=true to override".format(why), reason=why
        )
    return None


def _prepared(spec, run_, life):
    """The release written whole and checked, in the prepared state: its id."""
    doc, pinned = obtain_images(spec, run_.host)
    rid = life.releases.new_id(spec.spec_hash)
    record = Record(
        created=now(),
        spec_hash=spec.spec_hash,
        project=spec.name,
        images=pinned,
        deployed_by=run_.by,
        autostart=spec.autostart,
        run_id=run_.run_id,
    )
    try:
        life.prepare(rid, spec.to_dict(), compose_yaml(release_compose(doc)), record)
    except OSError as error:  # e.g. disk full: nothing half-written stays behind
        raise Failure("cannot write release {}: {}; the old release keeps running".format(rid, error)) from None
    refused = check_compose(spec.name, life.releases.path(rid, "compose.yaml"))
    if refused:
        life.discard(rid)
        raise Refusal(refused)
    return rid


def apply(spec, run_, life, lock=None):
    old = life.current()
    finish = _finisher(spec, run_, "apply")
    if already_current(spec, run_, life, old):
        return finish(results.ALREADY_CURRENT, "payload: release {} is already current".format(old), old)
    return _held(spec, run_, old, finish) or _switch(spec, run_, life, lock, _prepared(spec, run_, life), old, finish)


def prepare(spec, run_, life):
    """Everything of an apply before the switch; what runs is not touched.
    An earlier prepared release of the same spec is used again."""
    old = life.current()
    finish = _finisher(spec, run_, "prepare")
    if already_current(spec, run_, life, old):
        return finish(results.ALREADY_CURRENT, "payload: release {} is already current".format(old), old)
    for rid in reversed(life.releases.ids()):
        record = life.record(rid)
        if record and record.state == PREPARED and life.releases.spec(rid) == spec:
            return finish(results.PREPARED, "payload: release {} is prepared".format(rid), rid)
    rid = _prepared(spec, run_, life)
    return finish(results.PREPARED, "payload: release {} is prepared; `payloadctl switch` runs it".format(rid), rid)


def switch(rid, run_, life, lock=None):
    """The rest of an apply for a release `prepare` made, with its own spec."""
    known = rid in life.releases.ids()  # a release's name, never a path elsewhere
    record = life.record(rid) if known else None
    spec = life.releases.spec(rid) if known else None
    if record is None or record.state != PREPARED or spec is None:
        state = record.state if record else "missing"
        raise Refusal("release {} is {}, not prepared: nothing switched".format(rid, state))
    finish = _finisher(spec, run_, "switch")
    old = life.current()
    return _held(spec, run_, old, finish) or _switch(spec, run_, life, lock, rid, old, finish)


def _switch(spec, run_, life, lock, rid, old, finish):
    came_from = life.switch(rid).switch.came_from
    if not spec.autostart:
        life.stage(rid)
        gc(spec.keep_releases, life.releases)
        return finish(results.STAGED, "payload: release {} staged (no autostart)".format(rid), rid)
    ok, why, taken, restored = takeover.start_taking_over(spec, life, rid, old, came_from, run_.restart, lock)
    if ok:
        ok, why = health.run_checks(spec.name, spec.checks)
    if ok:
        life.keep(rid)
        # verified: Docker may bring it back (the spec's policies: what the pinned copy keeps)
        health.set_restart_policies(spec.name, restart_policies(spec.compose))
        gc(spec.keep_releases, life.releases)
        return finish(results.APPLIED, "payload: release {} is healthy".format(rid), rid, taken=taken)
    back = life.fail(rid, why, restored)
    if not back:
        return finish(
            results.FAILED,
            "payload: release {} failed: {}; no healthy release to roll back to (the next run tries again)".format(
                rid, why
            ),
            rid,
            why,
            taken,
        )
    back_ok, back_why = start.start_and_check(life.releases, life.releases.spec(back) or spec, run_.restart, lock)
    state = "and it is running" if back_ok else "but it is not healthy either: " + back_why
    return finish(
        results.ROLLED_BACK,
        "payload: release {} failed ({}); rolled back to {} {}".format(rid, why, back, state),
        rid,
        why,
        taken,
    )
