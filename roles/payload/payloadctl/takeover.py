"""Containers that run the payload another way (set up by hand or by an
older tool) are taken over by the first release: restart policy `no`, then
stopped, recorded in the release, and started again if that release fails
with nothing of ours to go back to.

Only an earlier copy of the payload is taken over by itself: a container
running the payload's primary image (its first service's) in no compose
project, or in a compose project this robot's payload is recorded to have
used (the current release's project, or one its release took over from).
Another compose project's container is left alone even when it runs the
same image (a home automation project on the robot is not ours to stop);
it is taken over only when payload_replaces names it (``container:NAME``)
or its compose project (``project:NAME``).

``reason`` is the rule, written once: the deploy side uses it to say what
will be taken over, the robot side to decide."""

import json

from . import health, imageref, start
from .system import log, now, run

COMPOSE_PROJECT = "com.docker.compose.project"


KINDS = ("container", "project")


def parse_replaces(entries):
    """payload_replaces (``container:NAME``, ``project:NAME``) as
    {"container": [...], "project": [...]}."""
    found = {kind: [] for kind in KINDS}
    for entry in entries or ():
        kind, _, name = entry.partition(":")
        found[kind].append(name)
    return found


def recorded_projects(record, project):
    """The compose projects ``record`` (the current release's, a dict) says
    this robot's payload used, other than ``project``: its own, and those of
    what it took over."""
    record = record or {}
    found = {record.get("project")} | {c.get("project") for c in record.get("taken_over") or () if isinstance(c, dict)}
    return sorted(p for p in found if isinstance(p, str) and p and p != project)


def reason(container, project, takeover, recorded=()):
    """Why the payload takes ``container`` over, or None.

    ``container``: name, project (its compose project or None), running,
    restart (its restart policy), repositories (of its image).
    ``takeover``: {"primary": the primary image's repository, "container":
    names, "project": compose projects} (the spec's); ``recorded``: compose
    projects this robot's payload used before.  A container of the
    payload's own project, or one that is stopped for good, never is."""
    if container["project"] == project:
        return None
    if not container["running"] and container["restart"] in ("", "no"):
        return None
    if container["name"] in takeover.get("container", ()):
        return "payload_replaces names it"
    if container["project"] and container["project"] in takeover.get("project", ()):
        return "payload_replaces names its compose project"
    if not (takeover.get("primary") and takeover["primary"] in container["repositories"]):
        return None
    if not container["project"]:
        return "it runs the payload's image"
    if container["project"] in recorded:
        return "it runs the payload's image in compose project {}, which this robot's payload used before".format(
            container["project"]
        )
    return None  # another compose project's, even of the same image


def described(data):
    """A `docker inspect` record as the rule reads it (repositories: of the
    image it was started with; ``image_repositories`` adds the rest)."""
    labels = data["Config"].get("Labels") or {}
    return {
        "id": data["Id"],
        "name": data["Name"].lstrip("/"),
        "image": data["Config"].get("Image"),
        "project": labels.get(COMPOSE_PROJECT),
        "running": bool(data["State"].get("Running")),
        "restart": (data["HostConfig"].get("RestartPolicy") or {}).get("Name") or "no",
        "repositories": [imageref.repository(data["Config"].get("Image") or "")],
    }


def image_repositories(data):
    """Every repository the container's image is tagged or pinned as (a
    container started from an image id still names its repository)."""
    repos = set()
    proc = run(["docker", "image", "inspect", data.get("Image") or ""], check=False)
    try:
        found = json.loads(proc.stdout or "[]") if proc.returncode == 0 else []
    except ValueError:
        found = []
    for image in found:
        repos |= {imageref.repository(r) for r in (image.get("RepoTags") or []) + (image.get("RepoDigests") or [])}
    return repos


def foreign_containers(spec, recorded=()):
    ids = run(["docker", "ps", "-aq", "--no-trunc"], check=False).stdout.split()
    found = []
    for data in health.inspect_containers(ids):
        container = described(data)
        if container["project"] == spec.name:
            continue
        container["repositories"] = sorted(set(container["repositories"]) | image_repositories(data))
        why = reason(container, spec.name, spec.takeover, recorded)
        if why:
            found.append(dict(container, why=why))
    return found


def take_over(found):
    """Restart policy `no` first (so nothing brings it back), then stop;
    each one said with why."""
    for c in found:
        where = "compose project {}, ".format(c["project"]) if c["project"] else ""
        log("payload: stopping {} ({}{}, restart {}): {}".format(c["name"], where, c["image"], c["restart"], c["why"]))
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


def recorded_of(life, rid, project):
    """recorded_projects of release ``rid`` (one an older payloadctl made
    names its project in its spec only)."""
    record = life.record(rid) if rid else None
    if record is None:
        return []
    recorded = set(recorded_projects(record.to_dict(), project))
    old_spec = life.releases.spec(rid) if not record.project else None
    return sorted(recorded | ({old_spec.name} - {project} if old_spec else set()))


def start_taking_over(spec, life, rid, before, came_from, restart, lock=None):
    """start.start_and_check, after stopping what the payload replaces
    (recorded in the release first): (healthy?, why not, what it took over,
    what it gave back).  ``before``: the release current before this one;
    ``came_from``: the verified one a failure goes back to.  If this release
    fails with nothing of ours to go back to, what it took over runs again
    as before (None: nothing given back)."""
    recorded = recorded_of(life, before, spec.name)
    found = foreign_containers(spec, recorded)
    if found:
        life.adopt(rid, found)
        take_over(found)
    ok, why = start.start_and_check(life.releases, spec, restart, lock)
    restored = None
    if not ok and found and not came_from:
        # Nothing of ours to go back to: our project makes way (also at boot).
        run(["systemctl", "stop", spec.name + ".service"], check=False)
        life.abandon(rid)
        restored = {"time": now(), "containers": restore(found)}
        why += "; restored what it had taken over: " + ", ".join(restored["containers"])
    return ok, why, found, restored
