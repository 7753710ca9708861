"""The releases on this robot: releases/<id>/ with compose.yaml, spec.json
and record.json; the `current` and `previous` pointers; what is kept."""

import datetime
import json
import os
import shutil
import time

from . import durable
from .spec import Spec
from .system import run

RUNS = "runs"


def compose_yaml(doc):
    """compose.yaml without PyYAML on the robot: JSON is valid YAML."""
    return "# Release compose file written by payloadctl; JSON is YAML.\n" + json.dumps(doc, indent=2) + "\n"


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
                durable.fsync_dir(self.root)
            return
        tmp = link + ".tmp"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(os.path.join("releases", rid), tmp)
        os.replace(tmp, link)
        durable.fsync_dir(self.root)

    def record(self, rid):
        return durable.read_json(self.path(rid, "record.json")) if rid else None

    def state(self, rid):
        return (self.record(rid) or {}).get("state")

    def write_record(self, rid, record):
        durable.write_json(self.path(rid, "record.json"), record)

    def spec(self, rid):
        """The spec release ``rid`` was made with (None: made by an older payloadctl)."""
        data = durable.read_json(self.path(rid, "spec.json")) if rid else None
        try:
            return Spec.from_dict(data) if data else None
        except ValueError:
            return None

    def write(self, rid, spec, compose_doc, record):
        """A new release's directory, written whole or not at all."""
        try:
            durable.make_private_dir(self.path(rid))
            durable.write_text(self.path(rid, "compose.yaml"), compose_yaml(compose_doc))
            durable.write_json(self.path(rid, "spec.json"), spec.to_dict())
            self.write_record(rid, record)
        except OSError:
            shutil.rmtree(self.path(rid), ignore_errors=True)
            raise

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


def gc(keep_releases, releases):
    """Keep current, previous and the newest few; their images stay."""
    keep = set(releases.all()[-keep_releases:])
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
