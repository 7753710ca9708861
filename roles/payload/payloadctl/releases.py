"""The releases on this robot as they are stored: releases/<id>/ with
compose.yaml, spec.json and record.json; the `current` and `previous`
pointers; what is kept.  Read only: records and pointers are written by
lifecycle.py alone."""

import datetime
import json
import os
import re
import shutil
import time

from . import durable
from .spec import Spec
from .system import run

RUNS = "runs"


RESTART_WHEN_VERIFIED = "x-restart-when-verified"  # service -> its restart policy, given once verified
DEPLOY_CONDITIONS = {"none": "no", "any": "always"}  # compose's deploy.restart_policy conditions as Docker's policies


def compose_yaml(doc):
    """compose.yaml without PyYAML on the robot: JSON is valid YAML."""
    return "# Release compose file written by payloadctl; JSON is YAML.\n" + json.dumps(doc, indent=2) + "\n"


def release_compose(doc):
    """The compose document a release is written with: every service with
    restart policy `no`, the policies they ask for kept under
    x-restart-when-verified (compose ignores x- keys).  So the one `compose
    up` that switches to an unverified release creates its containers
    without a policy (Docker cannot bring them back after a power cut before
    the boot's recovery decides), and the policies, given with `docker
    update` once the release is verified, never enter the containers'
    config hash: a later `compose up` of the same file recreates nothing."""
    services = {}
    for name, service in doc["services"].items():
        service = dict(service, restart="no")
        if isinstance(service.get("deploy"), dict) and "restart_policy" in service["deploy"]:
            service["deploy"] = {k: v for k, v in service["deploy"].items() if k != "restart_policy"}
        services[name] = service
    return dict(doc, services=services, **{RESTART_WHEN_VERIFIED: restart_policies(doc)})


def for_engine(doc, version):
    """The document as this robot's engine takes it: Docker Engine < 25
    refuses a health check's start_interval (compose then starts nothing),
    so it is dropped there and the check probes at its interval from the
    start.  An engine that does not say its version keeps it."""
    major = re.match(r"\d+", version or "")
    if not major or int(major.group()) >= 25:
        return doc
    services = {}
    for name, service in doc["services"].items():
        check = service.get("healthcheck")
        if isinstance(check, dict) and "start_interval" in check:
            service = dict(service, healthcheck={k: v for k, v in check.items() if k != "start_interval"})
        services[name] = service
    return dict(doc, services=services)


def restart_policies(doc):
    """service -> the restart policy it runs with once verified: from
    x-restart-when-verified, else (a file of an older payloadctl, or a spec's
    document) what its service asks compose for."""
    kept = doc.get(RESTART_WHEN_VERIFIED)
    if isinstance(kept, dict):
        return {name: str(policy) for name, policy in kept.items()}
    return {name: service_policy(service) for name, service in doc["services"].items()}


def service_policy(service):
    """The policy compose creates ``service``'s containers with (its
    deploy.restart_policy wins over restart, as in compose)."""
    deploy = service.get("deploy") if isinstance(service.get("deploy"), dict) else {}
    policy = deploy.get("restart_policy")
    if isinstance(policy, dict):
        condition = str(policy.get("condition") or "no")  # compose 2.x: no condition, no policy
        name = DEPLOY_CONDITIONS.get(condition, condition)
        attempts = policy.get("max_attempts")
        return "{}:{}".format(name, attempts) if name == "on-failure" and attempts else name
    return str(service.get("restart") or "no")


def grants_no_policy(doc):
    """Compose creates every container of ``doc`` with restart policy `no`
    (true of every file this payloadctl writes)."""
    return all(service_policy(service) == "no" for service in doc["services"].values())


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

    def raw_record(self, rid):
        """record.json as stored (None: missing or unreadable); lifecycle.Record reads it."""
        return durable.read_json(self.path(rid, "record.json")) if rid else None

    def spec(self, rid):
        """The spec release ``rid`` was made with (None: made by an older payloadctl)."""
        data = durable.read_json(self.path(rid, "spec.json")) if rid else None
        try:
            return Spec.from_dict(data) if data else None
        except ValueError:
            return None

    def ids(self):
        """Every release directory's name, sorted."""
        return sorted(os.listdir(self.dir)) if os.path.isdir(self.dir) else []

    def all(self):
        """The releases with a record, oldest first."""
        created = {r: (self.raw_record(r) or {}).get("created") for r in self.ids()}
        return sorted((r for r in created if created[r] is not None), key=lambda r: (str(created[r]), r))

    def new_id(self, spec_hash):
        base = datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%SZ") + "-" + spec_hash[:8]
        rid, n = base, 1
        while os.path.lexists(self.path(rid)):
            n += 1
            rid = "{}-{}".format(base, n)
        return rid


def gc(keep_releases, releases):
    """Keep current, previous and the newest few; their images stay."""
    keep = set(releases.all()[-keep_releases:])
    keep |= {releases.pointer("current"), releases.pointer("previous")}
    keep.discard(None)
    kept_images = set()
    for rid in keep:
        record = releases.raw_record(rid) or {}
        kept_images |= {i["id"] for i in (record.get("images") or {}).values()}
    for rid in releases.ids():
        if rid in keep:
            os.chmod(releases.path(rid), 0o700)  # releases written before 0700 was the rule
            continue
        # Also a directory a power cut left without its record (never switched to).
        record = releases.raw_record(rid) or {}
        shutil.rmtree(releases.path(rid), ignore_errors=True)
        for image in (record.get("images") or {}).values():
            if image["id"] not in kept_images:
                run(["docker", "image", "rm", image["pinned"]], check=False, timeout=120)
    runs = os.path.join(releases.root, RUNS)
    if os.path.isdir(runs):  # left by deploys whose operator vanished
        for name in os.listdir(runs):
            path = os.path.join(runs, name)
            if time.time() - os.lstat(path).st_mtime > 86400:
                shutil.rmtree(path, ignore_errors=True)
