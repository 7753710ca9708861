"""What runs on this robot, for the fleet status table (one JSON line)."""

import json

from . import health, results
from .lock import update_lock_holder
from .releases import Releases
from .system import run


def service_states(name):
    """service -> image, state, health, restarts of the project's containers."""
    found = {}
    for c in health.inspect_containers(health.project_containers(name)):
        service = (c["Config"].get("Labels") or {}).get("com.docker.compose.service", c["Name"].lstrip("/"))
        found[service] = {
            "image": c["Config"].get("Image"),
            "state": c["State"].get("Status"),
            "health": (c["State"].get("Health") or {}).get("Status"),
            "restarts": c.get("RestartCount", 0),
        }
    return found


# What status says of each kept release (its record holds more: images, the switch, the deploy's names).
KEPT_FIELDS = ("id", "state", "created", "activated", "reason")


def kept(releases):
    """The releases kept on the robot, newest first: what each was and when."""
    found = []
    for rid in reversed(releases.all()):
        record = releases.raw_record(rid) or {}
        found.append({key: record.get(key) for key in KEPT_FIELDS if record.get(key) is not None})
    return found


def graph_verdict(releases, name, rid):
    """ros_health's verdict on the graph now, one look: "ok" or what it
    lacks; None when release ``rid`` declares no graph (or is only staged)."""
    spec = releases.spec(rid) if rid else None
    checks = spec.checks if spec is not None and spec.autostart else ()
    wanted = next((c["graph"] for c in checks or () if isinstance(c, dict) and isinstance(c.get("graph"), dict)), None)
    if wanted is None:
        return None
    ok, why = health.graph_healthy(name, dict(wanted, wait=0))
    return "ok" if ok else why


def report(root, name, lock_file):
    releases = Releases(root)
    current, previous = releases.pointer("current"), releases.pointer("previous")
    version = run(["docker", "version", "-f", "{{.Server.Version}}"], check=False, timeout=60).stdout.strip()
    return {
        "docker_version": version or None,
        "current": releases.raw_record(current) if current else None,
        "previous": releases.raw_record(previous) if previous else None,
        "containers": health.states(name),
        "update_lock": update_lock_holder(lock_file) if lock_file else None,
        "services": service_states(name),
        "result": results.last(root),  # the last apply's or rollback's structured result
        "releases": kept(releases),
        "graph": graph_verdict(releases, name, current),
    }


def show(root, name, lock_file):
    print(json.dumps(report(root, name, lock_file), sort_keys=True))
    return 0
