"""Releases on removable media (robotfleet export; robotfleet/pull/robot/media.py):
`robotfleet export` run as an operator runs it, against a deploy repository,
a bare remote and a registry serving a two-platform image on 127.0.0.1,
writes a directory a robot verifies from; tampered, replayed, expired and
foreign-signed media are refused with the same reasons as over the network
(the same fixtures as tests/integration/test_pull_trust.py); the agent's wake
converges from a mounted medium, loads each image through a `docker` that
records its calls (the integration layer has no Docker engine: a real
`docker load` is covered end to end only), refuses an archive whose bytes
differ from the signed target, and writes its report to the medium when
the remote is out of reach, then pushes it at the next contact."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tarfile
from pathlib import Path

import pytest

from robotfleet.pull.operator import export as exporting
from robotfleet.pull.protocol import agent_files, media, reports
from robotfleet.pull.robot import agent_state
from tests.integration.mediaworld import FLEET, MACHINE, MediaWorld, exported, loads, media_fleet
from tests.integration.publishsite import git, robot_fetch, robotfleet_cmd
from tests.unit import pullkit
from tests.unit.pullkit import DAY, NOW, refused

refusals = pullkit.module("robot.refusals")


# -- the operator: robotfleet export --------------------------------------------


def test_export_writes_a_signed_repository_with_each_robot_s_image_archive_a_robot_verifies(site, image_registry):
    address, store, _ = image_registry
    (site["checkout"] / "inventories" / "robots.yaml").write_text(FLEET.format(registry=address))
    git(site["checkout"], "commit", "-qam", "media fleet")
    common = ("--checkout", site["checkout"], "--keys", site["keys"])
    robotfleet_cmd("publish", *common, "--no-wheels")
    medium = site["base"] / "usb"
    done = robotfleet_cmd("export", medium, *common, "--timestamp-expiry", "60d")
    assert "export: release 1 for 2 robot(s), 2 image archive(s)" in done.stdout, done.stdout
    trust = pullkit.module("robot.verify")
    trust.initialize(site["robot"], (medium / "metadata" / "root.json").read_bytes())
    client = trust.Client(site["robot"], str(medium))
    record = client.refresh()
    index = media.parse(client.download([media.NAME], site["base"] / "dl")[media.NAME].read_bytes())
    assert index["version"] == record.version == 1
    ref = f"{address}/ros/payload:1.0"
    for machine, arch in (("x86_64", "amd64"), ("aarch64", "arm64")):
        entry = index["images"][machine][ref]
        assert entry["digest"] == record.images_of("robot1")[ref] == record.images_of("robot2")[ref]
        assert entry["image"] == store.ids[arch]
        archive = client.download([entry["archive"]], site["base"] / "dl")[entry["archive"]]
        with tarfile.open(archive) as tar:
            saved = json.load(tar.extractfile("manifest.json"))[0]
            oci = json.load(tar.extractfile("index.json"))["manifests"][0]
            assert saved["RepoTags"] == [ref] and saved["Config"] == "blobs/sha256/" + store.ids[arch][7:]
            assert oci["digest"] == entry["digest"]  # the registry's own bytes: the containerd store keeps the pin
            assert (
                hashlib.sha256(tar.extractfile(f"blobs/sha256/{entry['digest'][7:]}").read()).hexdigest()
                == entry["digest"][7:]
            )
    # the releases branch carries the re-signed metadata, not the archives,
    # and a robot that took the media goes back to the network without a rollback
    listed = git(site["remote"], "ls-tree", "-r", "--name-only", "robotfleet/releases")
    assert "media.json" in listed and "images/" not in listed
    assert (
        git(site["remote"], "show", "robotfleet/releases:metadata/timestamp.json")
        == (medium / "metadata" / "timestamp.json").read_text().strip()
    )
    assert trust.Client(site["robot"], str(robot_fetch(site))).refresh().version == 1
    # exported again: the same release, its archives replaced, the media pruned to one set
    robotfleet_cmd("export", medium, *common)
    assert len(list((medium / "targets" / "images").iterdir())) == 2
    assert trust.Client(site["robot"], str(medium)).refresh().version == 1


def test_export_of_nothing_published_is_one_line(site):
    done = robotfleet_cmd(
        "export", site["base"] / "usb", "--checkout", site["checkout"], "--keys", site["keys"], check=False
    )
    assert done.returncode != 0 and done.stderr.strip().count("\n") == 0, done.stderr
    assert "export:" in done.stderr


# -- the robot's checks, on media as over the network --------------------------


def test_media_are_verified_like_the_network(tmp_path):
    fleet = media_fleet(tmp_path)
    assert fleet.refresh(source=exported(fleet, tmp_path / "usb")).version == 1


def test_tampered_media_are_refused(tmp_path):
    fleet = media_fleet(tmp_path)
    usb = exported(fleet, tmp_path / "usb")
    pullkit.edit_json(
        usb / "metadata" / "timestamp.json", lambda md: md["signed"].update(expires="2099-01-01T00:00:00Z")
    )
    assert refused(fleet, refusals.TAMPERED, source=usb).startswith("timestamp.json: changed after it was signed")


def test_replayed_older_media_are_refused_as_a_rollback(tmp_path):
    fleet = media_fleet(tmp_path)
    old = exported(fleet, tmp_path / "old-usb")
    fleet.release(2)
    assert fleet.refresh(source=exported(fleet, tmp_path / "usb")).version == 2
    assert "rollback" in refused(fleet, refusals.ROLLBACK, source=old)


def test_expired_media_are_refused_as_a_freeze(tmp_path):
    fleet = media_fleet(tmp_path, now=NOW - 10 * DAY)  # its timestamp (7 days) expired 3 days ago
    line = refused(fleet, refusals.EXPIRED, source=exported(fleet, tmp_path / "usb"))
    assert "expired" in line and "freeze" in line


def test_media_signed_by_another_fleet_s_keys_are_refused(tmp_path):
    fleet = media_fleet(tmp_path)
    other = media_fleet(tmp_path / "other", name="keys")
    line = refused(fleet, refusals.UNKNOWN_KEY, source=exported(other, tmp_path / "usb"))
    assert "does not trust" in line


def test_a_halt_after_an_export_halts_the_release_on_the_network_without_its_archives(tmp_path):
    from robotfleet.pull.operator import publishing

    fleet = media_fleet(tmp_path)
    halted = publishing.halt(fleet.repository, fleet.keys, "canary crash-loops", fleet.expiry, NOW)
    assert fleet.refresh().halt and halted.version == 2
    assert media.NAME not in fleet.repository.targets().signed.targets


# -- the agent's wake from a mounted medium ------------------------------------


@pytest.fixture
def world(tmp_path, image_registry):
    return MediaWorld(tmp_path, image_registry[0])


def test_a_robot_converges_from_a_mounted_medium_and_writes_its_report_there(world, docker, monkeypatch):
    world.release(1)
    report, outcome, sent = world.wake()
    assert (outcome.result, outcome.reason) == ("applied", "release 1 applied"), outcome.reason
    assert len(loads(docker)) == 1
    assert ["image", "inspect", "--format", "{{json .Id}}", f"{world.ref.rsplit(':', 1)[0]}@{world.digest}"] in docker()
    # the remote is out of reach: the report is on the medium, and waits for the next contact
    assert sent.startswith("report not sent") and f"written to {world.usb}/reports/robot1.json" in sent
    written = reports.parse((world.usb / "reports" / "robot1.json").read_bytes(), "robot1")
    assert written["result"] == "applied" and written["applied"]["version"] == 1
    world.config = agent_files.Config(**{**world.config.__dict__, "remote": f"file://{world.bare}"})
    _, outcome, sent = world.wake()
    assert (outcome.result, sent) == ("up-to-date", "report sent")
    assert world.pushed_report()["applied"]["version"] == 1
    assert len(loads(docker)) == 1  # nothing loaded again


def test_an_image_archive_whose_bytes_differ_from_the_signed_target_is_refused(world, docker):
    world.release(1)
    stored = next((world.usb / "targets" / "images").iterdir())
    data = bytearray(stored.read_bytes())
    data[-2000] ^= 1
    stored.write_bytes(bytes(data))
    report, outcome, _ = world.wake()
    assert (outcome.result, outcome.refusal) == ("refused", "tampered"), outcome.reason
    assert outcome.reason.startswith(f"{world.archive}: does not match what was signed"), outcome.reason
    assert loads(docker) == []  # never given to docker
    assert not agent_state.load_state(world.state).get("applied")


def test_on_the_classic_image_store_the_checked_image_id_is_tagged_by_the_release_s_digest(world, docker, monkeypatch):
    """The classic store keeps no registry digest for a loaded image: the id
    it loaded is checked against the release's, then tagged by the digest
    (the payload runs that tag: tests/integration/test_payloadctl_images.py)."""
    monkeypatch.setenv("FAKE_DOCKER_MODE", "classic")
    world.release(1)
    _, outcome, _ = world.wake()
    assert outcome.result == "applied" and len(loads(docker)) == 1, outcome.reason
    tag = f"{world.ref.rsplit(':', 1)[0]}:media-sha256-{world.digest[7:]}"
    assert ["tag", world.image, tag] in docker()
    assert json.loads(Path(os.environ["FAKE_DOCKER_STORE"]).read_text())[tag] == world.image
    _, outcome, _ = world.wake()
    assert outcome.result == "up-to-date" and len(loads(docker)) == 1


def test_a_loaded_image_whose_id_is_not_the_release_s_is_refused_and_not_tagged(world, docker, monkeypatch):
    monkeypatch.setenv("FAKE_DOCKER_MODE", "classic")
    world.release(1)
    index = media.parse((world.base / media.NAME).read_bytes())
    index["images"][MACHINE][world.ref]["image"] = "sha256:" + "0" * 64  # signed, but not what the archive holds
    (world.base / media.NAME).write_bytes(media.build(1, index["images"]))
    repository = pullkit.module("operator.repository")
    world.fleet.repository.extend(
        {}, world.fleet.keys.signer("online"), world.fleet.expiry, NOW, replacing=[media.NAME]
    )
    world.fleet.repository.extend(
        {media.NAME: world.base / media.NAME}, world.fleet.keys.signer("online"), world.fleet.expiry, NOW
    )
    exporting.copy_out(world.fleet.repository, repository.Repository(world.usb))
    _, outcome, _ = world.wake()
    assert (outcome.result, outcome.refusal) == ("refused", "tampered"), outcome.reason
    assert "the release binds sha256:" + "0" * 64 in outcome.reason
    assert not [call for call in docker() if call[0] == "tag"]


def test_without_a_medium_mounted_the_robot_fetches_from_its_remote(world, docker):
    world.release(1)
    shutil.rmtree(world.usb)
    _, outcome, _ = world.wake()
    assert outcome.result == "failed" and outcome.reason.startswith("fetch:"), outcome.reason
    assert docker() == []
