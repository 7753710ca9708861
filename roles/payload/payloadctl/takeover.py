"""Containers that run the payload another way (set up by hand or by an
older tool) are taken over by the first release: restart policy `no`, then
stopped, recorded in the release, and started again if that release fails
with nothing of ours to go back to.

Only what looks like an earlier copy of the payload is taken over by itself:
a container running the payload's primary image (its first service's), in
no compose project or in the one the old setup used.  A container that runs
a common image one of the services also uses (a broker, a database) belongs
to someone else; it is taken over only when payload_replaces names it
(``container:NAME``) or its compose project (``project:NAME``).

``reason`` is the rule, written once: the deploy side uses it to say what
will be taken over, the robot side to decide."""

import json

from . import durable, health, imageref
from .releases import Releases
from .system import now, run

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


def reason(container, project, takeover):
    """Why the payload takes ``container`` over, or None.

    ``container``: name, project (its compose project or None), running,
    restart (its restart policy), repositories (of its image).
    ``takeover``: {"primary": the primary image's repository, "container":
    names, "project": compose projects} (the spec's).  A container of the
    payload's own project, or one that is stopped for good, never is."""
    if container["project"] == project:
        return None
    if not container["running"] and container["restart"] in ("", "no"):
        return None
    if container["name"] in takeover.get("container", ()):
        return "payload_replaces names it"
    if container["project"] and container["project"] in takeover.get("project", ()):
        return "payload_replaces names its compose project"
    if takeover.get("primary") and takeover["primary"] in container["repositories"]:
        return "it runs the payload's image"
    return None


def described(data):
    """A `docker inspect` record as the rule reads it (repositories: of the
    image it was started with; ``image_repositories`` adds the rest)."""
    labels = data["Config"].get("Labels") or {}
    return {"id": data["Id"], "name": data["Name"].lstrip("/"), "image": data["Config"].get("Image"),
            "project": labels.get(COMPOSE_PROJECT), "running": bool(data["State"].get("Running")),
            "restart": (data["HostConfig"].get("RestartPolicy") or {}).get("Name") or "no",
            "repositories": [imageref.repository(data["Config"].get("Image") or "")]}


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


def foreign_containers(spec):
    ids = run(["docker", "ps", "-aq", "--no-trunc"], check=False).stdout.split()
    found = []
    for data in health.inspect_containers(ids):
        container = described(data)
        if container["project"] == spec.name:
            continue
        container["repositories"] = sorted(set(container["repositories"]) | image_repositories(data))
        why = reason(container, spec.name, spec.takeover)
        if why:
            found.append(dict(container, why=why))
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


def start_taking_over(spec, releases, rid, record, old, restart, lock=None):
    """health.start_and_check, after stopping what the payload replaces
    (recorded in the release first); if this release fails and there is no
    release of ours to go back to, what was taken over runs again as before."""
    found = foreign_containers(spec)
    if found:
        record["taken_over"] = found
        durable.write_json(releases.path(rid, "record.json"), record)
        take_over(found)
    ok, why = health.start_and_check(spec, restart, lock)
    if not ok and found and not old:
        # Nothing of ours to go back to: our project makes way (also at boot).
        run(["systemctl", "stop", spec.name + ".service"], check=False)
        Releases(spec.dir).point("current", None)
        record["restored"] = {"time": now(), "containers": restore(found)}
        why += "; restored what it had taken over: " + ", ".join(record["restored"]["containers"])
    return ok, why
