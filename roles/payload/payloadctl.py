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
import fcntl
import json
import os
import shutil
import subprocess
import sys
import time

RESULT = "last-result.json"


class Failure(Exception):
    pass


def log(message):
    print(message, flush=True)


def run(args, check=True, input_text=None):
    proc = subprocess.run(
        args, input=input_text, stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True
    )
    if check and proc.returncode != 0:
        raise Failure("{} failed: {}".format(" ".join(args[:3]), (proc.stderr or proc.stdout).strip()[-400:]))
    return proc


def now():
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


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
            return
        tmp = link + ".tmp"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(os.path.join("releases", rid), tmp)
        os.replace(tmp, link)

    def record(self, rid):
        try:
            with open(self.path(rid, "record.json")) as handle:
                return json.load(handle)
        except (OSError, ValueError):
            return None

    def write_record(self, rid, record):
        write_json(self.path(rid, "record.json"), record)

    def all(self):
        if not os.path.isdir(self.dir):
            return []
        found = [r for r in os.listdir(self.dir) if self.record(r) is not None]
        return sorted(found, key=lambda r: self.record(r).get("created", ""))


def write_json(path, data):
    tmp = path + ".tmp"
    with open(tmp, "w") as handle:
        json.dump(data, handle, indent=2, sort_keys=True)
        handle.write("\n")
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)


def write_text(path, text):
    tmp = path + ".tmp"
    with open(tmp, "w") as handle:
        handle.write(text)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)


def compose_yaml(doc):
    """compose.yaml without PyYAML on the robot: JSON is valid YAML."""
    return "# Release compose file written by payloadctl; JSON is YAML.\n" + json.dumps(doc, indent=2) + "\n"


# --- images -----------------------------------------------------------------


def image_info(ref):
    proc = run(["docker", "image", "inspect", ref], check=False)
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


def obtain(ref, delivery):
    """Make the image present, pulling while the old release keeps running."""
    if delivery == "pull":
        last = ""
        for attempt in range(3):
            proc = run(["docker", "pull", "-q", ref], check=False)
            if proc.returncode == 0:
                break
            last = (proc.stderr or proc.stdout).strip()[-300:]
            time.sleep(2 * (attempt + 1))
        else:
            if image_info(ref) is None:
                raise Failure("cannot pull {}: {}".format(ref, last))
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
    proc = run(["docker", "ps", "-aq", "--filter", "label=com.docker.compose.project=" + name], check=False)
    return proc.stdout.split()


def container_state(cid):
    proc = run(["docker", "inspect", cid], check=False)
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


def wait_healthy(name, timeout, stable_seconds):
    """(True, "") once every container is healthy (HEALTHCHECK) or has run
    without restarting for stable_seconds; (False, why) otherwise."""
    deadline = time.time() + timeout
    first_restarts = {}
    stable_since = None
    why = "no container started"
    while time.time() < deadline:
        states = [s for s in (container_state(c) for c in project_containers(name)) if s]
        if states:
            all_ok, stable_needed = True, False
            for s in states:
                first_restarts.setdefault(s["name"], s["restarts"])
                if s["health"] == "unhealthy":
                    return False, "{} is unhealthy: {}".format(s["name"], s["health_log"] or "health check failed")
                if s["status"] != "running":
                    all_ok = False
                    why = "{} is {} (exit code {})".format(s["name"], s["status"], s["exit_code"])
                elif s["health"] == "starting":
                    all_ok = False
                    why = "{} health check still starting".format(s["name"])
                elif s["health"] is None:
                    stable_needed = True
                    if s["restarts"] != first_restarts[s["name"]]:
                        stable_since = None
                        first_restarts[s["name"]] = s["restarts"]
                        all_ok = False
                        why = "{} restarted".format(s["name"])
            if all_ok:
                if not stable_needed:
                    return True, ""
                stable_since = stable_since or time.time()
                if time.time() - stable_since >= stable_seconds:
                    return True, ""
                why = "waiting for {} s without restarts".format(stable_seconds)
            else:
                stable_since = None
        time.sleep(1)
    return False, "not healthy after {} s: {}".format(timeout, why)


def unit_active(unit):
    return run(["systemctl", "is-active", "--quiet", unit], check=False).returncode == 0


def start_release(name, restart):
    """Run `current` through the payload's unit."""
    unit = name + ".service"
    if restart or not unit_active(unit):
        run(["systemctl", "restart", unit])
    else:
        run(["systemctl", "reload", unit])


def start_and_check(name, restart, timeout, stable_seconds):
    """Bring `current` up and wait for it: (healthy?, why not)."""
    try:
        start_release(name, restart)
        return wait_healthy(name, timeout, stable_seconds)
    except Failure as error:
        return False, str(error)


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


class Lock:
    def __init__(self, path):
        self.path = path

    def __enter__(self):
        self.handle = open(self.path, "w")
        fcntl.flock(self.handle, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc):
        fcntl.flock(self.handle, fcntl.LOCK_UN)
        self.handle.close()


def update_lock_holder(path):
    if not os.path.exists(path):
        return None
    try:
        with open(path) as handle:
            reason = handle.read().strip()[:200]
    except OSError:
        reason = ""
    return reason or "no reason given"


def finish(root, ok, message, release=None):
    write_json(os.path.join(root, RESULT), {"ok": ok, "message": message, "release": release, "time": now()})
    log(message)
    return 0 if ok else 1


def cmd_apply(args):
    with open(args.spec) as handle:
        spec = json.load(handle)
    root = spec["dir"]
    releases = Releases(root)
    os.makedirs(releases.dir, exist_ok=True)
    with Lock(os.path.join(root, ".apply.lock")):
        old = releases.pointer("current")
        try:
            return apply_locked(spec, releases, old, args.restart)
        except Failure as error:
            return finish(root, False, "payload: {}".format(error))
        except Exception as error:  # record it: the deploy reads the result, not our stderr
            return finish(root, False, "payload: internal error in payloadctl: {!r}".format(error))


def apply_locked(spec, releases, old, restart):
    root = spec["dir"]
    # An apply that waited for another one (e.g. a rerun after a dropped SSH
    # link) may find the work done: switching again would restart for nothing.
    running = releases.record(old) if old else None
    if (
        running
        and not restart
        and running.get("spec_hash") == spec["spec_hash"]
        and running.get("state") in ("active", "staged")
        and (not spec["autostart"] or unit_active(spec["name"] + ".service"))
    ):
        return finish(root, True, "payload: release {} is already current".format(old), old)
    holder = update_lock_holder(spec["lock_file"])
    if holder and old and not spec.get("force"):
        return finish(
            root,
            False,
            "payload: update refused, {} is held ({}); run again with --data payload_force=true to override".format(
                spec["lock_file"], holder
            ),
        )
    doc = spec["compose"]
    images = {}
    for service in doc["services"].values():
        ref = service["image"]
        info = obtain(ref, spec["delivery"])
        service["image"] = pinned(ref, info)
        images[ref] = {"id": info["id"], "pinned": service["image"]}
    rid = datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%SZ") + "-" + spec["spec_hash"][:8]
    os.makedirs(releases.path(rid), exist_ok=True)
    write_text(releases.path(rid, "compose.yaml"), compose_yaml(doc))
    check_compose(spec["name"], releases.path(rid, "compose.yaml"))  # issue 13 hook
    record = {
        "id": rid,
        "created": now(),
        "spec_hash": spec["spec_hash"],
        "images": images,
        "deployed_by": spec.get("deployed_by", "unknown"),
        "autostart": spec["autostart"],
        "state": "switching",
    }
    releases.write_record(rid, record)
    before_previous = releases.pointer("previous")
    if old and old != rid:
        releases.point("previous", old)
    releases.point("current", rid)
    if not spec["autostart"]:
        record["state"] = "staged"
        releases.write_record(rid, record)
        gc(spec, releases)
        return finish(root, True, "payload: release {} staged (no autostart)".format(rid), rid)
    ok, why = start_taking_over(spec, releases.path(rid, "record.json"), record, old, restart)  # issue 13 hook
    if ok:
        ok, why = gpu_check(spec["name"], spec.get("gpu_check"))
    if ok:
        record["state"] = "active"
        record["activated"] = now()
        releases.write_record(rid, record)
        gc(spec, releases)
        return finish(root, True, "payload: release {} is healthy".format(rid), rid)
    record["state"] = "failed"
    record["reason"] = why
    releases.write_record(rid, record)
    if not old:
        return finish(root, False, "payload: release {} failed: {}; no previous release to roll back to".format(rid, why), rid)
    releases.point("current", old)
    releases.point("previous", before_previous)
    back = releases.record(old) or {}
    back["rolled_back_from"] = {"id": rid, "reason": why, "time": now()}
    releases.write_record(old, back)
    back_ok, back_why = start_and_check(spec["name"], restart, spec["health_timeout"], spec["stable_seconds"])
    state = "and it is running" if back_ok else "but it is not healthy either: " + back_why
    return finish(
        root, False, "payload: release {} failed ({}); rolled back to {} {}".format(rid, why, old, state), old
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
            continue
        record = releases.record(rid) or {}
        shutil.rmtree(releases.path(rid), ignore_errors=True)
        for image in record.get("images", {}).values():
            if image["id"] not in kept_images:
                run(["docker", "image", "rm", image["pinned"]], check=False)


def cmd_rollback(args):
    root = args.dir
    releases = Releases(root)
    with Lock(os.path.join(root, ".apply.lock")):
        current, previous = releases.pointer("current"), releases.pointer("previous")
        if not previous:
            return finish(root, False, "payload: no previous release to roll back to")
        holder = update_lock_holder(args.lock_file) if args.lock_file else None
        if holder and not args.force:
            return finish(root, False, "payload: rollback refused, {} is held ({})".format(args.lock_file, holder))
        releases.point("current", previous)
        releases.point("previous", current)
        record = releases.record(previous) or {}
        record["rolled_back_to"] = now()
        releases.write_record(previous, record)
        if not record.get("autostart", True):
            return finish(root, True, "payload: rolled back to {} (staged)".format(previous), previous)
        ok, why = start_and_check(args.name, False, args.health_timeout, args.stable_seconds)
        if ok:
            return finish(root, True, "payload: rolled back from {} to {}".format(current, previous), previous)
        return finish(root, False, "payload: rolled back to {} but it is not healthy: {}".format(previous, why), previous)


def cmd_result(args):
    try:
        with open(os.path.join(args.dir, RESULT)) as handle:
            result = json.load(handle)
    except (OSError, ValueError):
        print("payload: no result recorded (did the update run?)", file=sys.stderr)
        return 1
    stream = sys.stdout if result["ok"] else sys.stderr
    print(result["message"], file=stream)
    return 0 if result["ok"] else 1


def cmd_status(args):
    releases = Releases(args.dir)
    current, previous = releases.pointer("current"), releases.pointer("previous")
    version = run(["docker", "version", "-f", "{{.Server.Version}}"], check=False).stdout.strip()
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
    p.set_defaults(func=cmd_apply)
    for name, func in (("rollback", cmd_rollback), ("result", cmd_result), ("status", cmd_status)):
        p = sub.add_parser(name)
        p.add_argument("--dir", required=True)
        p.add_argument("--name", default="robot-payload")
        p.add_argument("--lock-file")
        p.add_argument("--force", action="store_true")
        p.add_argument("--health-timeout", type=int, default=120)
        p.add_argument("--stable-seconds", type=int, default=10)
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
