"""A robot's pull agent converging from removable media, as the media tests
(tests/integration/test_pull_media*.py, test_pull_export_medium.py) drive it:
a fleet file (FLEET), a `docker` that records its calls (FAKE_DOCKER: the
integration layer has no Docker engine), the registry's image also served
by its digest, a signed repository with a media index (media_fleet) copied
out to a medium (exported), and pullworld's robot whose release pins an
image of the registry, exported with its archive (MediaWorld).
tests/integration/conftest.py's ``docker`` and ``image_registry`` fixtures
use them."""

from __future__ import annotations

import hashlib
import json
import os
import stat
import sys
from pathlib import Path

from robotfleet.pull.operator import export as exporting
from robotfleet.pull.protocol import agent_files, media, platforms
from tests.integration.pullworld import World
from tests.unit import pullkit
from tests.unit.pullkit import NOW

MACHINE = platforms.parse_platform(platforms.platform_key())[1]
FLEET = """\
all:
  vars:
    payload_image: {registry}/ros/payload:1.0
robots:
  vars:
    pull_enabled: true
    pull_remote: https://git.example.com/fleet.git
  hosts:
    robot1: {{address: 127.0.0.1}}
    robot2: {{address: 127.0.0.1, pull_platform: cp311-aarch64}}
"""

# A `docker` for the agent: records each call, keeps the images it loaded in
# a JSON file, answers `image inspect` from it.  MODE containerd: a loaded
# OCI index's name finds its digest and the image's id is that digest (as
# the containerd image store does); classic: only the tag, the id the
# config's digest (as the classic store does).
FAKE_DOCKER = """#!{python}
import hashlib, json, os, sys, tarfile
args = sys.argv[1:]
with open(os.environ["FAKE_DOCKER_LOG"], "a") as log:
    log.write(json.dumps(args) + "\\n")
path = os.environ["FAKE_DOCKER_STORE"]
store = json.load(open(path)) if os.path.exists(path) else {{}}
if args[:2] == ["image", "inspect"]:
    if args[-1] not in store:
        sys.exit("Error response from daemon: No such image: " + args[-1])
    print(json.dumps(store[args[-1]]))
elif args[0] == "load":
    with tarfile.open(args[args.index("-i") + 1]) as archive:
        saved = json.load(archive.extractfile("manifest.json"))[0]
        config = archive.extractfile(saved["Config"]).read()
        image_id = "sha256:" + hashlib.sha256(config).hexdigest()
        if os.environ.get("FAKE_DOCKER_MODE") == "classic":
            store.update({{tag: image_id for tag in saved["RepoTags"]}})
        else:
            for entry in json.load(archive.extractfile("index.json"))["manifests"]:
                name = entry["annotations"]["io.containerd.image.name"]
                repository = name.rsplit(":", 1)[0] if ":" in name.rsplit("/", 1)[-1] else name
                store.update({{name: entry["digest"], repository + "@" + entry["digest"]: entry["digest"]}})
    print("Loaded image: " + saved["RepoTags"][0])
elif args[0] == "tag":
    if args[1] not in store and args[1] not in store.values():
        sys.exit("Error response from daemon: No such image: " + args[1])
    store[args[2]] = store.get(args[1], args[1])
json.dump(store, open(path, "w"))
"""


def by_its_digest(platform_registry):
    """conftest's platform_registry, its index also served by its digest (as registries do)."""
    address, store, fetched = platform_registry
    store.manifests["sha256:" + hashlib.sha256(store.manifests["1.0"][1]).hexdigest()] = store.manifests["1.0"]
    return address, store, fetched


def fake_docker(tmp_path: Path, monkeypatch):
    """FAKE_DOCKER first on PATH (where payloadctl image-load finds docker), its
    log and store in tmp_path: a function returning the calls made so far."""
    program = tmp_path / "bin" / "docker"
    program.parent.mkdir()
    program.write_text(FAKE_DOCKER.format(python=sys.executable))
    program.chmod(program.stat().st_mode | stat.S_IXUSR)
    log = tmp_path / "docker.log"
    monkeypatch.setenv("PATH", f"{program.parent}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("FAKE_DOCKER_LOG", str(log))
    monkeypatch.setenv("FAKE_DOCKER_STORE", str(tmp_path / "docker-images.json"))

    def calls() -> list[list[str]]:
        return [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []

    return calls


def media_fleet(base: Path, now=NOW, name="keys", expiry=None) -> pullkit.Fleet:
    """A repository whose release 1 carries a media index, and a robot trusting it."""
    fleet = pullkit.Fleet(base, now=now, name=name)
    fleet.release(1, now=now, expiry=expiry)
    index = base / "media.json"
    index.write_bytes(media.build(1, {}))
    fleet.repository.extend({media.NAME: index}, fleet.keys.signer("online"), expiry or fleet.expiry, now)
    fleet.trust()
    return fleet


def exported(fleet: pullkit.Fleet, where: Path) -> Path:
    exporting.copy_out(fleet.repository, pullkit.module("operator.repository").Repository(where))
    return where


class MediaWorld(World):
    """pullworld's robot (a release whose converge answers as the
    contract says), whose release pins an image of the registry, exported
    with its archive for this machine to ``usb``."""

    def __init__(self, base: Path, address: str):
        super().__init__(base)
        self.ref = f"{address}/ros/payload:1.0"
        self.usb = base / "usb"
        self.config = agent_files.Config(
            **{**self.config.__dict__, "media_dir": str(self.usb), "remote": f"file://{base}/out-of-reach.git"}
        )

    def release(self, version: int, robots=("robot1", "robot2"), archive=None, canary="1"):
        repository = pullkit.module("operator.repository")
        from roles.payload.registry import Registry

        address, _, path = self.ref.partition("/")
        _, _, digest = Registry(address).manifest(path.rsplit(":", 1)[0], "1.0")
        built, built_archive = self.record(version, robots, canary, images={r: {self.ref: digest} for r in robots})
        signer = self.fleet.keys.signer("online")
        self.fleet.repository.publish(built, {built.code: archive or built_archive}, signer, self.fleet.expiry, NOW)
        from roles.payload import media_archive

        name = media.archive_path(f"v{version}", MACHINE)
        local = self.base / name
        local.parent.mkdir(parents=True, exist_ok=True)
        image = media_archive.write(self.ref, digest, MACHINE, local, [], None)
        (self.base / media.NAME).write_bytes(
            media.build(version, {MACHINE: {self.ref: {"digest": digest, "archive": name, "image": image}}})
        )
        usb = repository.Repository(self.usb)
        self.fleet.repository.extend(
            {media.NAME: self.base / media.NAME, name: local}, signer, self.fleet.expiry, NOW, elsewhere={name}
        )
        exporting.copy_out(self.fleet.repository, usb, {name: local})
        self.digest, self.image, self.archive = digest, image, name
        return built


def loads(calls) -> list[list[str]]:
    return [call for call in calls() if call[0] == "load"]
