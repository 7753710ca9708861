#!/usr/bin/env python3
# Managed by the robot fleet provisioner (roles/payload).
"""payloadctl: releases of this robot's payload.

A release is a directory releases/<id>/ holding compose.yaml (images pinned
by digest where the registry gave one) and record.json.  `current` and
`previous` are symlinks; the systemd unit runs `current`.  `apply` runs on
the robot itself (started by the deploy as a transient systemd unit), so a
dropped SSH link cannot leave the robot half-switched:

  download first -> switch -> wait healthy -> keep, or switch back.

Standard library only, Python >= 3.8 (Ubuntu 20.04).
"""

import argparse
import datetime
import errno
import fcntl
import json
import os
import shutil
import socket
import stat
import subprocess
import sys
import time

RESULT = "last-result.json"
RUNS = "runs"
GOOD = ("active", "staged")
POLL = 0.5  # seconds between health looks: a crash is seen within about this


class Failure(Exception):
    pass


def log(message):
    print(message, flush=True)


def run(args, check=True, input_text=None, timeout=None):
    proc = subprocess.run(
        args, input=input_text, stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True,
        timeout=timeout,
    )
    if check and proc.returncode != 0:
        raise Failure("{} failed: {}".format(" ".join(args[:3]), (proc.stderr or proc.stdout).strip()[-400:]))
    return proc


def now():
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def precise_now():
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


# --- durable files ------------------------------------------------------------
# A power cut must never leave an empty record, compose file or pointer: write
# a temp file, fsync it, rename it, then fsync the directory (the rename is
# only durable once the directory is).


def fsync_dir(path):
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_bytes(path, data, mode=0o600):
    tmp = path + ".tmp"
    if os.path.lexists(tmp):
        os.unlink(tmp)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), mode)
    try:
        os.fchmod(fd, mode)
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
        os.fsync(fd)
    except BaseException:
        os.close(fd)
        os.unlink(tmp)
        raise
    os.close(fd)
    os.replace(tmp, path)
    fsync_dir(os.path.dirname(path) or ".")


def write_json(path, data):
    write_bytes(path, (json.dumps(data, indent=2, sort_keys=True) + "\n").encode())


def write_text(path, text):
    write_bytes(path, text.encode())


def make_private_dir(path):
    """A directory only root can read (it may hold payload secrets)."""
    os.makedirs(path, mode=0o700, exist_ok=True)
    os.chmod(path, 0o700)


class Releases:
    def __init__(self, root):
        self.root = root
        self.dir = os.path.join(root, "releases")

    def path(self, rid, *parts):
        return os.path.join(self.dir, rid, *parts)

    def pointer(self, name):
        link = os.path.join(self.root, name)
        if not os.path.islink(link):
            return None
        return os.path.basename(os.readlink(link))

    def point(self, name, rid):
        link = os.path.join(self.root, name)
        if rid is None:
            if os.path.lexists(link):
                os.unlink(link)
                fsync_dir(self.root)
            return
        tmp = link + ".tmp"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(os.path.join("releases", rid), tmp)
        os.replace(tmp, link)
        fsync_dir(self.root)

    def record(self, rid):
        if not rid:
            return None
        try:
            with open(self.path(rid, "record.json")) as handle:
                return json.load(handle)
        except (OSError, ValueError):
            return None

    def state(self, rid):
        return (self.record(rid) or {}).get("state")

    def write_record(self, rid, record):
        write_json(self.path(rid, "record.json"), record)

    def all(self):
        if not os.path.isdir(self.dir):
            return []
        found = [r for r in os.listdir(self.dir) if self.record(r) is not None]
        return sorted(found, key=lambda r: self.record(r).get("created", ""))

    def new_id(self, spec_hash):
        base = datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%SZ") + "-" + spec_hash[:8]
        rid, n = base, 1
        while os.path.lexists(self.path(rid)):
            n += 1
            rid = "{}-{}".format(base, n)
        return rid


def compose_yaml(doc):
    """compose.yaml without PyYAML on the robot: JSON is valid YAML."""
    return "# Release compose file written by payloadctl; JSON is YAML.\n" + json.dumps(doc, indent=2) + "\n"


# --- images -----------------------------------------------------------------


def image_info(ref):
    proc = run(["docker", "image", "inspect", ref], check=False, timeout=60)
    if proc.returncode != 0:
        return None
    data = json.loads(proc.stdout)[0]
    return {"id": data["Id"], "repo_digests": data.get("RepoDigests") or []}


def repository(ref):
    name = ref.split("@", 1)[0]
    last = name.rsplit("/", 1)[-1]
    if ":" in last:
        name = name[: len(name) - len(last)] + last.split(":", 1)[0]
    return name


def pull(ref, timeout):
    """docker pull, three tries, all within `timeout` seconds; the error text."""
    deadline = time.time() + timeout
    last = ""
    for attempt in range(3):
        left = deadline - time.time()
        if left <= 0:
            break
        try:
            proc = run(["docker", "pull", "-q", ref], check=False, timeout=left)
        except subprocess.TimeoutExpired:
            raise Failure(
                "docker pull {} did not finish within {} s (payload_pull_timeout); "
                "the old release keeps running".format(ref, timeout)
            )
        if proc.returncode == 0:
            return None
        last = (proc.stderr or proc.stdout).strip()[-300:]
        time.sleep(min(2 * (attempt + 1), max(0, deadline - time.time())))
    return last or "gave up after {} s (payload_pull_timeout)".format(timeout)


def obtain(ref, delivery, pull_timeout=300):
    """Make the image present, pulling while the old release keeps running."""
    if delivery == "pull":
        error = pull(ref, pull_timeout)
        if error is not None and image_info(ref) is None:
            raise Failure("cannot pull {}: {}; the old release keeps running".format(ref, error))
    info = image_info(ref)
    if info is None:
        raise Failure("image {} is not on this robot (delivery: {})".format(ref, delivery))
    return info


def pinned(ref, info):
    repo = repository(ref)
    for digest_ref in info["repo_digests"]:
        if repository(digest_ref) == repo:
            return digest_ref
    return ref


# --- containers ---------------------------------------------------------------


def project_containers(name):
    proc = run(["docker", "ps", "-aq", "--filter", "label=com.docker.compose.project=" + name], check=False, timeout=60)
    return proc.stdout.split()


def container_state(cid):
    proc = run(["docker", "inspect", cid], check=False, timeout=60)
    if proc.returncode != 0:
        return None
    data = json.loads(proc.stdout)[0]
    state = data["State"]
    health = state.get("Health") or {}
    log_tail = ""
    if health.get("Log"):
        log_tail = (health["Log"][-1].get("Output") or "").strip()[-200:]
    return {
        "name": data["Name"].lstrip("/"),
        "image": data["Config"]["Image"],
        "image_id": data["Image"],
        "status": state["Status"],
        "health": health.get("Status"),
        "health_log": log_tail,
        "restarts": data.get("RestartCount", 0),
        "started": state.get("StartedAt"),
        "exit_code": state.get("ExitCode"),
    }


def verdict(states, baseline):
    """One look at the containers: ("ok" | "wait" | "fail" | "stable", why).

    A container that has exited, is restarting or restarted since the first
    look, or that Docker's HEALTHCHECK calls unhealthy, fails the release at
    once: waiting out the health timeout would only keep a broken payload."""
    if not states:
        return "wait", "no container started"
    outcome, why = "ok", ""
    for s in states:
        baseline.setdefault(s["name"], s["restarts"])
        if s["status"] in ("exited", "dead"):
            return "fail", "{} exited with code {}".format(s["name"], s["exit_code"])
        if s["status"] == "restarting" or s["restarts"] > baseline[s["name"]]:
            return "fail", "{} is crash-looping (restarted {} times, last exit code {})".format(
                s["name"], s["restarts"], s["exit_code"])
        if s["health"] == "unhealthy":
            return "fail", "{} is unhealthy: {}".format(s["name"], s["health_log"] or "health check failed")
        if s["status"] != "running":
            outcome, why = "wait", "{} is {}".format(s["name"], s["status"])
        elif s["health"] == "starting":
            outcome, why = "wait", "{} health check still starting".format(s["name"])
        elif s["health"] is None and outcome == "ok":
            outcome = "stable"
    return outcome, why


def wait_healthy(name, timeout, stable_seconds):
    """(True, "") once every container is healthy (HEALTHCHECK) or has run
    without restarting for stable_seconds; (False, why) at the first sign of
    failure or when `timeout` runs out."""
    deadline = time.time() + timeout
    baseline = {}
    stable_since = None
    why = "no container started"
    while True:
        states = [s for s in (container_state(c) for c in project_containers(name)) if s]
        outcome, reason = verdict(states, baseline)
        if outcome == "fail":
            return False, reason
        if outcome == "ok":
            return True, ""
        if outcome == "stable":
            stable_since = stable_since or time.time()
            if time.time() - stable_since >= stable_seconds:
                return True, ""
            why = "waiting for {} s without restarts".format(stable_seconds)
        else:
            stable_since = None
            why = reason
        if time.time() >= deadline:
            return False, "not healthy after {} s (payload_health_timeout): {}".format(timeout, why)
        time.sleep(POLL)


def containers_up(name):
    """The payload really runs: containers exist, all running, none unhealthy."""
    states = [s for s in (container_state(c) for c in project_containers(name)) if s]
    return bool(states) and all(s["status"] == "running" and s["health"] != "unhealthy" for s in states)


def unit_active(unit):
    return run(["systemctl", "is-active", "--quiet", unit], check=False, timeout=60).returncode == 0


def start_release(name, restart):
    """Run `current` through the payload's unit."""
    unit = name + ".service"
    if restart or not unit_active(unit):
        run(["systemctl", "restart", unit], timeout=600)
    else:
        run(["systemctl", "reload", unit], timeout=600)


def start_and_check(name, restart, timeout, stable_seconds):
    """Bring `current` up and wait for it: (healthy?, why not)."""
    try:
        start_release(name, restart)
        return wait_healthy(name, timeout, stable_seconds)
    except Failure as error:
        return False, str(error)
    except subprocess.TimeoutExpired as error:
        return False, "{} did not finish within {} s".format(" ".join(error.cmd[:3]), error.timeout)


# --- locks --------------------------------------------------------------------


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
            write_json(self.owner_path, dict(self.owner, since=now(), pid=os.getpid()))
        except OSError:
            pass  # the owner note is a courtesy to waiters; the lock holds without it
        return self

    def busy_message(self):
        try:
            with open(self.owner_path) as handle:
                owner = json.load(handle)
        except (OSError, ValueError):
            owner = {}
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


# --- results --------------------------------------------------------------------


def run_dir(root, run_id):
    return os.path.join(root, RUNS, run_id)


def finish(root, ok, message, release=None, run_id=None):
    result = {"ok": ok, "message": message, "release": release, "time": now(), "run_id": run_id}
    log(message)
    if run_id:
        make_private_dir(run_dir(root, run_id))
        write_json(os.path.join(run_dir(root, run_id), "result.json"), result)
    write_json(os.path.join(root, RESULT), result)
    return 0 if ok else 1


# --- recovery -----------------------------------------------------------------


def recover(releases):
    """Undo a switch that never finished (power cut or crash between the
    switch and its verdict).  `current` in state "switching" carries where it
    came from; if that release was good, go back to it.  Returns a line for
    the log, or None when there was nothing to undo."""
    rid = releases.pointer("current")
    record = releases.record(rid)
    if not record or record.get("state") != "switching":
        return None
    switch = record.get("switch") or {}
    back = switch.get("from")
    if not back or back == rid or releases.state(back) not in GOOD:
        return None  # nothing verified to go back to: run it, the next deploy re-releases it
    releases.point("current", back)
    releases.point("previous", switch.get("previous_before"))
    record.pop("switch", None)
    why = "interrupted before it was verified healthy (power cut, reboot or crash)"
    if switch.get("kind") == "rollback":
        record["state"] = switch.get("prior_state") or "active"
        record["rollback_interrupted"] = {"time": now(), "reason": why}
    else:
        record["state"] = "failed"
        record["reason"] = why
    releases.write_record(rid, record)
    back_record = releases.record(back) or {}
    back_record["rolled_back_from"] = {"id": rid, "reason": why, "time": now()}
    releases.write_record(back, back_record)
    return "payload: release {} was {}; back on {}".format(rid, why, back)


# --- GPU check (roles/gpu) -----------------------------------------------------


def gpu_check(name, command):
    """(True, "") when ``command`` (e.g. nvidia-smi -L) succeeds in every
    container of the project; (False, why) for the first that cannot see a GPU."""
    if not command:
        return True, ""
    for cid in project_containers(name):
        proc = run(["docker", "exec", cid] + list(command), check=False)
        if proc.returncode != 0:
            who = (container_state(cid) or {}).get("name", cid)
            said = (proc.stderr or proc.stdout).strip()[-200:] or "exit {}".format(proc.returncode)
            return False, "{} cannot see a GPU ({} failed: {})".format(who, " ".join(command), said)
    return True, ""


# --- commands -----------------------------------------------------------------


def cmd_apply(args):
    with open(args.spec) as handle:
        spec = json.load(handle)
    if args.run_id:
        spec["run_id"] = args.run_id
    root = spec["dir"]
    run_id = spec.get("run_id")
    releases = Releases(root)
    make_private_dir(releases.dir)
    owner = {"by": spec.get("deployed_by", "unknown"), "action": "apply", "run_id": run_id}
    return locked(releases, spec.get("apply_lock_timeout", 300), owner,
                  lambda: apply_locked(spec, releases, releases.pointer("current"), args.restart))


def locked(releases, lock_timeout, owner, work):
    """Run ``work`` holding the robot's one apply/rollback lock, after undoing
    a switch a power cut left unverified; every outcome is recorded as this
    run's result (the deploy reads the result, not our stderr)."""
    root, run_id = releases.root, owner["run_id"]
    lock = Lock(root, lock_timeout, owner)
    try:
        lock.acquire()
    except Busy as busy:
        return finish(root, False, "payload: {}".format(busy), run_id=run_id)
    try:
        recovered = recover(releases)
        if recovered:
            log(recovered)
        return work()
    except Failure as error:
        return finish(root, False, "payload: {}".format(error), run_id=run_id)
    except OSError as error:
        return finish(root, False, "payload: cannot write on this robot: {}".format(error), run_id=run_id)
    except Exception as error:
        return finish(root, False, "payload: internal error in payloadctl ({}): {!r}".format(owner["action"], error),
                      run_id=run_id)
    finally:
        lock.release()


def apply_locked(spec, releases, old, restart):
    root = spec["dir"]
    run_id = spec.get("run_id")
    # An apply that waited for another one (two deploys at once, or a rerun
    # after a dropped SSH link) may find the work done.
    running = releases.record(old) if old else None
    if (
        running
        and not restart
        and running.get("spec_hash") == spec["spec_hash"]
        and running.get("state") in GOOD
        and (not spec["autostart"] or containers_up(spec["name"]))
    ):
        return finish(root, True, "payload: release {} is already current".format(old), old, run_id)
    holder = update_lock_holder(spec["lock_file"])
    if holder and old and not spec.get("force"):
        return finish(
            root,
            False,
            "payload: update refused, {} is held ({}); run again with --data payload_force=true to override".format(
                spec["lock_file"], holder
            ),
            run_id=run_id,
        )
    doc = spec["compose"]
    images = {}
    for service in doc["services"].values():
        ref = service["image"]
        info = obtain(ref, spec["delivery"], spec.get("pull_timeout", 300))
        service["image"] = pinned(ref, info)
        images[ref] = {"id": info["id"], "pinned": service["image"]}
    rid = releases.new_id(spec["spec_hash"])
    before_previous = releases.pointer("previous")
    good_old = old if old and releases.state(old) in GOOD else None
    record = {
        "id": rid,
        "created": now(),
        "spec_hash": spec["spec_hash"],
        "images": images,
        "deployed_by": spec.get("deployed_by", "unknown"),
        "autostart": spec["autostart"],
        "run_id": run_id,
        "state": "switching",
        "switch": {"kind": "apply", "from": good_old, "previous_before": before_previous},
    }
    try:
        make_private_dir(releases.path(rid))
        write_text(releases.path(rid, "compose.yaml"), compose_yaml(doc))
        releases.write_record(rid, record)
    except OSError as error:  # e.g. disk full: nothing half-written stays behind
        shutil.rmtree(releases.path(rid), ignore_errors=True)
        raise Failure("cannot write release {}: {}; the old release keeps running".format(rid, error))
    check_compose(spec["name"], releases.path(rid, "compose.yaml"))  # issue 13 hook
    if good_old and good_old != rid:
        releases.point("previous", good_old)
    releases.point("current", rid)
    record["switched"] = precise_now()
    if not spec["autostart"]:
        record["state"] = "staged"
        record.pop("switch")
        releases.write_record(rid, record)
        gc(spec, releases)
        return finish(root, True, "payload: release {} staged (no autostart)".format(rid), rid, run_id)
    ok, why = start_taking_over(spec, releases.path(rid, "record.json"), record, good_old, restart)  # issue 13 hook
    if ok:
        ok, why = gpu_check(spec["name"], spec.get("gpu_check"))
    record.pop("switch")
    if ok:
        record["state"] = "active"
        record["activated"] = now()
        releases.write_record(rid, record)
        gc(spec, releases)
        return finish(root, True, "payload: release {} is healthy".format(rid), rid, run_id)
    record["state"] = "failed"
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
    back_ok, back_why = start_and_check(spec["name"], restart, spec["health_timeout"], spec["stable_seconds"])
    state = "and it is running" if back_ok else "but it is not healthy either: " + back_why
    return finish(
        root, False, "payload: release {} failed ({}); rolled back to {} {}".format(rid, why, good_old, state),
        good_old, run_id,
    )


def gc(spec, releases):
    """Keep current, previous and the newest few; their images stay."""
    keep = set(releases.all()[-spec["keep_releases"]:])
    keep |= {releases.pointer("current"), releases.pointer("previous")}
    keep.discard(None)
    kept_images = set()
    for rid in keep:
        record = releases.record(rid) or {}
        kept_images |= {i["id"] for i in record.get("images", {}).values()}
    for rid in releases.all():
        if rid in keep:
            os.chmod(releases.path(rid), 0o700)  # releases written before 0700 was the rule
            continue
        record = releases.record(rid) or {}
        shutil.rmtree(releases.path(rid), ignore_errors=True)
        for image in record.get("images", {}).values():
            if image["id"] not in kept_images:
                run(["docker", "image", "rm", image["pinned"]], check=False, timeout=120)
    runs = os.path.join(releases.root, RUNS)
    if os.path.isdir(runs):  # left by deploys whose operator vanished
        for name in os.listdir(runs):
            path = os.path.join(runs, name)
            if time.time() - os.lstat(path).st_mtime > 86400:
                shutil.rmtree(path, ignore_errors=True)


def cmd_rollback(args):
    releases = Releases(args.dir)
    owner = {"by": args.by or "unknown", "action": "rollback", "run_id": args.run_id}
    return locked(releases, args.apply_lock_timeout, owner, lambda: rollback_locked(args, releases))


def rollback_locked(args, releases):
    """All or nothing: the previous release runs healthy, or `current` and
    `previous` are put back and the release that ran before is started again."""
    root, run_id = args.dir, args.run_id
    current, previous = releases.pointer("current"), releases.pointer("previous")
    target = releases.record(previous)
    if not previous or target is None:
        return finish(root, False, "payload: no previous release to roll back to", run_id=run_id)
    holder = update_lock_holder(args.lock_file) if args.lock_file else None
    if holder and not args.force:
        return finish(root, False, "payload: rollback refused, {} is held ({})".format(args.lock_file, holder),
                      run_id=run_id)
    prior_state = target.get("state")
    target["state"] = "switching"
    target["switch"] = {"kind": "rollback", "from": current, "previous_before": previous, "prior_state": prior_state}
    releases.write_record(previous, target)
    releases.point("current", previous)
    releases.point("previous", current)
    target["switched"] = precise_now()
    if not target.get("autostart", True):
        target.pop("switch")
        target["state"] = "staged"
        target["rolled_back_to"] = now()
        releases.write_record(previous, target)
        return finish(root, True, "payload: rolled back to {} (staged)".format(previous), previous, run_id)
    ok, why = start_and_check(args.name, False, args.health_timeout, args.stable_seconds)
    target.pop("switch")
    if ok:
        target["state"] = "active"
        target["rolled_back_to"] = now()
        releases.write_record(previous, target)
        return finish(root, True, "payload: rolled back from {} to {}".format(current, previous), previous, run_id)
    releases.point("current", current)
    releases.point("previous", previous)
    target["state"] = prior_state
    target["rollback_failed"] = {"time": now(), "reason": why}
    releases.write_record(previous, target)
    back_ok, back_why = start_and_check(args.name, False, args.health_timeout, args.stable_seconds)
    state = "and it is running" if back_ok else "but it is not healthy either: " + back_why
    return finish(
        root, False,
        "payload: rollback to {} failed ({}); restored {} {}".format(previous, why, current, state),
        current, run_id,
    )


def cmd_start(args):
    """The unit's ExecStart (boot): never run an unverified release blindly.
    When no apply holds the lock, a `current` left "switching" by a power cut
    is undone first; then the current release is brought up."""
    releases = Releases(args.dir)
    lock = Lock(args.dir, 0, {"by": "boot", "action": "start"})
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
    compose = os.path.join(args.dir, "current", "compose.yaml")
    os.execvp("docker", ["docker", "compose", "-p", args.name, "-f", compose, "up", "-d", "--remove-orphans"])


def cmd_result(args):
    """Print this run's result and exit with it; a missing result is a failure."""
    path = os.path.join(run_dir(args.dir, args.run_id), "result.json") if args.run_id else os.path.join(args.dir, RESULT)
    try:
        with open(path) as handle:
            result = json.load(handle)
    except (OSError, ValueError):
        result = None
    if not result or (args.run_id and result.get("run_id") != args.run_id):
        print(
            "payload: payloadctl recorded no result for this run ({}): disk full? see journalctl -u '{}-*-{}' on the robot".format(
                args.run_id, args.name, args.run_id),
            file=sys.stderr,
        )
        code = 1
    else:
        stream = sys.stdout if result["ok"] else sys.stderr
        print(result["message"], file=stream)
        code = 0 if result["ok"] else 1
    if args.run_id:
        shutil.rmtree(run_dir(args.dir, args.run_id), ignore_errors=True)
    return code


def cmd_status(args):
    releases = Releases(args.dir)
    current, previous = releases.pointer("current"), releases.pointer("previous")
    version = run(["docker", "version", "-f", "{{.Server.Version}}"], check=False, timeout=60).stdout.strip()
    containers = [s for s in (container_state(c) for c in project_containers(args.name)) if s]
    status = {
        "docker_version": version or None,
        "current": releases.record(current) if current else None,
        "previous": releases.record(previous) if previous else None,
        "containers": containers,
        "update_lock": update_lock_holder(args.lock_file) if args.lock_file else None,
    }
    status["services"] = service_states(args.name)  # issue 13 hook
    print(json.dumps(status, sort_keys=True))
    return 0


def cmd_wait_devices(args):
    deadline = time.time() + args.timeout
    while True:
        missing = [d for d in args.devices if not os.path.exists(d)]
        if not missing:
            return 0
        if time.time() >= deadline:
            print("payload: sensors missing after {} s: {}".format(args.timeout, " ".join(missing)), file=sys.stderr)
            return 1
        time.sleep(1)


# --- the compose project: config check, takeover, per-service status ----------
# (issue 13)  Called from three one-line hooks: check_compose in apply before
# anything switches, start_taking_over in place of apply's first
# start_and_check, service_states in status.

COMPOSE_PROJECT = "com.docker.compose.project"


def check_compose(name, path):
    """`docker compose config -q` on the robot before the release switches;
    a refused file leaves no release directory behind."""
    proc = run(["docker", "compose", "-p", name, "-f", path, "config", "-q"], check=False)
    if proc.returncode != 0:
        shutil.rmtree(os.path.dirname(path), ignore_errors=True)
        why = (proc.stderr or proc.stdout).strip().splitlines() or ["no output"]
        raise Failure("docker compose config refused the release (nothing switched): {}".format(why[-1][-300:]))


def inspect_all(ids):
    if not ids:
        return []
    proc = run(["docker", "inspect"] + list(ids), check=False)
    try:
        return json.loads(proc.stdout or "[]")
    except ValueError:
        return []


def image_repositories(container):
    repos = {repository(container["Config"].get("Image") or "")}
    info = inspect_all_images([container.get("Image")])
    for image in info:
        repos |= {repository(r) for r in (image.get("RepoTags") or []) + (image.get("RepoDigests") or [])}
    repos.discard("")
    return repos


def inspect_all_images(ids):
    ids = [i for i in ids if i]
    if not ids:
        return []
    proc = run(["docker", "image", "inspect"] + ids, check=False)
    try:
        return json.loads(proc.stdout or "[]")
    except ValueError:
        return []


def foreign_containers(spec):
    """Containers that are not this project's but run one of its image
    repositories (or are named in payload_replaces, by container name or
    compose project), and are running or would come back by their policy."""
    doc = spec["compose"]
    repos = {repository(s["image"]) for s in doc["services"].values() if s.get("image")}
    replaces = set((doc.get("x-robot-fleet") or {}).get("replaces") or [])
    ids = run(["docker", "ps", "-aq", "--no-trunc"], check=False).stdout.split()
    found = []
    for c in inspect_all(ids):
        labels = c["Config"].get("Labels") or {}
        project = labels.get(COMPOSE_PROJECT)
        if project == spec["name"]:
            continue
        name = c["Name"].lstrip("/")
        policy = (c["HostConfig"].get("RestartPolicy") or {}).get("Name") or "no"
        running = bool(c["State"].get("Running"))
        if not running and policy == "no":
            continue
        if name in replaces or (project and project in replaces) or image_repositories(c) & repos:
            found.append({"id": c["Id"], "name": name, "image": c["Config"].get("Image"),
                          "project": project, "restart": policy, "running": running})
    return found


def take_over(found):
    """Restart policy `no` first (so nothing brings it back), then stop."""
    for c in found:
        run(["docker", "update", "--restart", "no", c["id"]])
        if c["running"]:
            run(["docker", "stop", c["id"]])
    return found


def restore(taken):
    back = []
    for c in taken:
        ok = run(["docker", "update", "--restart", c["restart"], c["id"]], check=False).returncode == 0
        if c["running"]:
            ok = run(["docker", "start", c["id"]], check=False).returncode == 0 and ok
        back.append(c["name"] if ok else c["name"] + " (failed)")
    return back


def start_taking_over(spec, record_path, record, old, restart):
    """start_and_check, after stopping what the payload replaces (recorded in
    the release first); if this release fails and there is no release of
    ours to go back to, what was taken over runs again as before."""
    found = foreign_containers(spec)
    if found:
        record["taken_over"] = found
        write_json(record_path, record)
        take_over(found)
    ok, why = start_and_check(spec["name"], restart, spec["health_timeout"], spec["stable_seconds"])
    if not ok and found and not old:
        # Nothing of ours to go back to: our project makes way (also at boot).
        run(["systemctl", "stop", spec["name"] + ".service"], check=False)
        Releases(spec["dir"]).point("current", None)
        record["restored"] = {"time": now(), "containers": restore(found)}
        why += "; restored what it had taken over: " + ", ".join(record["restored"]["containers"])
    return ok, why


def service_states(name):
    """service -> image, state, health, restarts of the project's containers."""
    states = {}
    for c in inspect_all(project_containers(name)):
        service = (c["Config"].get("Labels") or {}).get("com.docker.compose.service", c["Name"].lstrip("/"))
        health = (c["State"].get("Health") or {}).get("Status")
        states[service] = {"image": c["Config"].get("Image"), "state": c["State"].get("Status"),
                           "health": health, "restarts": c.get("RestartCount", 0)}
    return states


def main(argv=None):
    parser = argparse.ArgumentParser(prog="payloadctl")
    sub = parser.add_subparsers(dest="command")
    p = sub.add_parser("apply")
    p.add_argument("spec")
    p.add_argument("--restart", action="store_true")
    p.add_argument("--run-id")
    p.set_defaults(func=cmd_apply)
    for name, func in (("rollback", cmd_rollback), ("result", cmd_result), ("status", cmd_status), ("start", cmd_start)):
        p = sub.add_parser(name)
        p.add_argument("--dir", required=True)
        p.add_argument("--name", default="robot-payload")
        p.add_argument("--lock-file")
        p.add_argument("--force", action="store_true")
        p.add_argument("--health-timeout", type=int, default=120)
        p.add_argument("--stable-seconds", type=int, default=10)
        p.add_argument("--apply-lock-timeout", type=int, default=300)
        p.add_argument("--run-id")
        p.add_argument("--by")
        p.set_defaults(func=func)
    p = sub.add_parser("wait-devices")
    p.add_argument("--timeout", type=int, default=30)
    p.add_argument("devices", nargs="+")
    p.set_defaults(func=cmd_wait_devices)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
