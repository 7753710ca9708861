"""A release on media, its pure parts: the image index ``media.json``
(robotfleet/pull/protocol/media.py) is read field by field with one line per
problem, and the tag payloadctl image-load gives a checked image on Docker's classic
store is the one the payload runs (payloadctl/images.py); the processes:
tests/integration/test_pull_media.py."""

from __future__ import annotations

import json

import pytest

from robotfleet.pull.protocol import media
from robotfleet.pull.robot import media as robot_media
from roles.payload.payloadctl import images

PIN, IMAGE = "sha256:" + "a" * 64, "sha256:" + "b" * 64
ENTRY = {"digest": PIN, "archive": "images/0123-x86_64.tar", "image": IMAGE}


def test_an_index_is_written_and_read_back():
    data = media.build(3, {"x86_64": {"reg.lan:5000/ros/payload:1.1": ENTRY}})
    assert media.parse(data) == {"version": 3, "images": {"x86_64": {"reg.lan:5000/ros/payload:1.1": ENTRY}}}
    assert media.build(3, {"x86_64": {"reg.lan:5000/ros/payload:1.1": ENTRY}}) == data


@pytest.mark.parametrize(
    "change, line",
    [
        (lambda d: d.update(format=2), "media.json: format: expected 1 (a newer robotfleet wrote these media?), got 2"),
        (lambda d: d.update(extra=1), "media.json: the index: expected exactly format, version and images"),
        (lambda d: d.update(version=0), "media.json: version: expected an integer >= 1, got 0"),
        (lambda d: d["images"].update(sparc={}), "media.json: images.sparc: expected x86_64, aarch64 or armv7l"),
        (
            lambda d: d["images"]["x86_64"]["r:1"].update(digest="sha256:x"),
            "media.json: images.x86_64.r:1.digest: expected sha256:<64 hex digits>, got 'sha256:x'",
        ),
        (
            lambda d: d["images"]["x86_64"]["r:1"].update(archive="../../etc/passwd"),
            "media.json: images.x86_64.r:1.archive: expected a target path images/<name>.tar",
        ),
        (
            lambda d: d["images"]["x86_64"]["r:1"].update(archive="images/a/../b.tar"),
            "media.json: images.x86_64.r:1.archive: expected a target path images/<name>.tar",
        ),
    ],
)
def test_every_bad_field_is_one_line_naming_it(change, line):
    data = {"format": 1, "version": 1, "images": {"x86_64": {"r:1": dict(ENTRY)}}}
    change(data)
    with pytest.raises(media.MediaError) as caught:
        media.parse(json.dumps(data).encode())
    assert str(caught.value).startswith(line) and "\n" not in str(caught.value)


def test_a_checked_image_is_tagged_by_the_name_the_payload_runs():
    """payloadctl image-load tags it so (agent_images.py) and runs it so (images.py)."""
    for ref, repository in (
        ("reg.lan:5000/ros/payload:1.1", "reg.lan:5000/ros/payload"),
        ("ros/payload:2", "ros/payload"),
        ("localhost:5000/p", "localhost:5000/p"),
    ):
        assert images.media_tag(f"{ref}@{PIN}") == f"{repository}:media-sha256-{PIN[7:]}"
    assert images.media_tag("reg.lan:5000/p:1") is None


def test_the_agent_s_configuration_carries_the_media_directory_when_one_is_set():
    from robotfleet.pull.protocol import agent_files

    config = agent_files.Config(robot="robot1", remote="ssh://g@h/fleet", media_dir="/mnt/fleet-media")
    assert agent_files.read_config(config.to_json()).media_dir == "/mnt/fleet-media"
    assert "media_dir" not in agent_files.Config(robot="robot1", remote="ssh://g@h/fleet").to_json()
    relative = config.to_json().replace('"/mnt/fleet-media"', '"mnt/fleet-media"')
    with pytest.raises(agent_files.ConfigError) as caught:
        agent_files.read_config(relative, "agent.json")
    assert str(caught.value) == "agent.json: media_dir: expected an absolute path or null"


def test_a_medium_is_mounted_only_when_it_holds_a_repository(tmp_path):
    assert robot_media.mounted(None) is None and robot_media.mounted(str(tmp_path)) is None
    (tmp_path / "metadata").mkdir()
    (tmp_path / "metadata" / "timestamp.json").write_text("{}")
    assert robot_media.mounted(str(tmp_path)) == tmp_path
