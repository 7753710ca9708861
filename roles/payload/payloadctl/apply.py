"""A release: download first, switch, wait healthy, keep it or switch back.

Runs holding the robot's apply lock (cli.locked); a power cut at any point
is undone at boot (recovery.py) or by the next deploy."""

import os
import shutil

from . import health, images, platforms, takeover
from . import spec as states
from .lock import update_lock_holder
from .releases import gc
from .results import finish
from .system import Failure, now, precise_now, run


def already_current(spec, run_, releases, old):
    """An apply that waited for another one (two deploys at once, or a rerun
    after a dropped SSH link) may find the work done."""
    running = releases.record(old) if old else None
    return bool(
        running
        and not run_.restart
        and running.get("spec_hash") == spec.spec_hash
        and running.get("state") in states.SETTLED
        and (not spec.autostart or health.containers_up(spec.name))
    )


def obtain_images(spec, robot):
    """Every service's image present, built for this robot's platform, and
    pinned: (compose with pinned images, {ref: {id, pinned, platform}}).
    An image for another platform is refused here, before the switch."""
    doc = {**spec.compose, "services": {k: dict(v) for k, v in spec.compose["services"].items()}}
    found = {}
    arch = images.robot_arch()
    for service in doc["services"].values():
        ref = service["image"]
        info = images.obtain(ref, spec.delivery, spec.pull_timeout, service.get("platform"))
        images.check_platform(ref, info, robot, arch)
        service["image"] = images.pinned(ref, info)
        found[ref] = {"id": info["id"], "pinned": service["image"], "platform": platforms.text(info["platform"])}
    return doc, found


def check_compose(name, path):
    """`docker compose config -q` on the robot before the release switches;
    a refused file leaves no release directory behind."""
    proc = run(["docker", "compose", "-p", name, "-f", path, "config", "-q"], check=False)
    if proc.returncode != 0:
        shutil.rmtree(os.path.dirname(path), ignore_errors=True)
        why = (proc.stderr or proc.stdout).strip().splitlines() or ["no output"]
        raise Failure("docker compose config refused the release (nothing switched): {}".format(why[-1][-300:]))


def apply(spec, run_, releases, lock=None):
    root, run_id = spec.dir, run_.run_id
    old = releases.pointer("current")
    if already_current(spec, run_, releases, old):
        return finish(root, True, "payload: release {} is already current".format(old), old, run_id)
    holder = update_lock_holder(spec.lock_file)
    if holder and old and not run_.force:
        return finish(
            root, False,
            "payload: update refused, {} is held ({}); run again with --data payload_force=true to override".format(
                spec.lock_file, holder),
            run_id=run_id,
        )
    doc, pinned = obtain_images(spec, run_.host)
    rid = releases.new_id(spec.spec_hash)
    before_previous = releases.pointer("previous")
    good_old = old if old and releases.state(old) in states.SETTLED else None
    record = {
        "id": rid,
        "created": now(),
        "spec_hash": spec.spec_hash,
        "images": pinned,
        "deployed_by": run_.by,
        "autostart": spec.autostart,
        "run_id": run_id,
        "state": states.SWITCHING,
        "switch": {"kind": "apply", "from": good_old, "previous_before": before_previous},
    }
    try:
        releases.write(rid, spec, doc, record)
    except OSError as error:  # e.g. disk full: nothing half-written stays behind
        raise Failure("cannot write release {}: {}; the old release keeps running".format(rid, error))
    check_compose(spec.name, releases.path(rid, "compose.yaml"))
    if good_old and good_old != rid:
        releases.point("previous", good_old)
    releases.point("current", rid)
    record["switched"] = precise_now()
    if not spec.autostart:
        record["state"] = states.STAGED
        record.pop("switch")
        releases.write_record(rid, record)
        gc(spec.keep_releases, releases)
        return finish(root, True, "payload: release {} staged (no autostart)".format(rid), rid, run_id)
    ok, why = takeover.start_taking_over(spec, releases, rid, record, good_old, run_.restart, lock)
    if ok:
        ok, why = health.run_checks(spec.name, spec.checks)
    record.pop("switch")
    if ok:
        record["state"] = states.ACTIVE
        record["activated"] = now()
        releases.write_record(rid, record)
        health.set_restart_policies(spec.name, health.restart_policies(doc))  # verified: Docker may bring it back
        gc(spec.keep_releases, releases)
        return finish(root, True, "payload: release {} is healthy".format(rid), rid, run_id)
    return roll_back(spec, run_, releases, lock, rid, record, why, good_old, before_previous)


def roll_back(spec, run_, releases, lock, rid, record, why, good_old, before_previous):
    """The release failed: record why, and go back to the release before it
    (if there was a verified one)."""
    root, run_id = spec.dir, run_.run_id
    record["state"] = states.FAILED
    record["reason"] = why
    record["failed"] = precise_now()
    releases.write_record(rid, record)
    if not good_old:
        return finish(
            root, False,
            "payload: release {} failed: {}; no healthy release to roll back to (the next run tries again)".format(rid, why),
            rid, run_id)
    releases.point("current", good_old)
    releases.point("previous", before_previous)
    back = releases.record(good_old) or {}
    back["rolled_back_from"] = {"id": rid, "reason": why, "time": now()}
    releases.write_record(good_old, back)
    back_ok, back_why = health.start_and_check(releases.spec(good_old) or spec, run_.restart, lock)
    state = "and it is running" if back_ok else "but it is not healthy either: " + back_why
    return finish(
        root, False, "payload: release {} failed ({}); rolled back to {} {}".format(rid, why, good_old, state),
        good_old, run_id,
    )
