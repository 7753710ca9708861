"""Prefetch's pure parts (robotfleet/pull/robot/prefetch.py): what Docker is
asked to pull, and whether the disk has room; the benchmark's window; the
image helper agent.json names."""

import datetime
import json

import pytest

from robotfleet.pull.protocol import agent_files
from robotfleet.pull.robot import prefetch
from tests.bench import prefetch as bench

DIGEST = "sha256:" + "a" * 64
MB = 1 << 20


def test_an_image_reference_and_its_digest_make_what_docker_pulls():
    assert prefetch.by_digest("reg.lan:5000/ros/payload:1.1", DIGEST) == f"reg.lan:5000/ros/payload@{DIGEST}"
    assert prefetch.by_digest("reg.lan:5000/ros/payload", DIGEST) == f"reg.lan:5000/ros/payload@{DIGEST}"
    assert prefetch.by_digest(f"payload:1@{DIGEST}", DIGEST) == f"payload@{DIGEST}"
    for ref, pin in (("-oProxy=x/payload:1", DIGEST), ("payload:1", "sha256:abc"), ("pay load:1", DIGEST)):
        with pytest.raises(ValueError, match="not an image reference and a sha256 digest"):
            prefetch.by_digest(ref, pin)


def test_room_keeps_pull_min_free_mb_free_after_the_downloads():
    assert prefetch.room(600 * MB, 88 * MB, 512, "/var/lib/robot-pull") is None
    assert prefetch.room(600 * MB, 89 * MB, 512, "/var/lib/robot-pull") == (
        "it needs about 89 MB, 600 MB are free on /var/lib/robot-pull's file system (pull_min_free_mb: 512)"
    )
    assert prefetch.room(10 * MB, 0, 0, "/x") is None


def test_the_benchmark_s_window_opens_at_a_whole_minute_after_its_lead():
    now = datetime.datetime(2026, 11, 27, 23, 50, 30, tzinfo=datetime.timezone.utc)
    opens, window = bench.window_ahead(now, lead=240)
    assert opens == datetime.datetime(2026, 11, 27, 23, 55, tzinfo=datetime.timezone.utc)
    assert window == "daily 23:55-00:25 UTC"  # past midnight: an end before the start
    assert bench.window_ahead(now.replace(second=0), lead=240)[0] == now.replace(minute=54, second=0)


def test_agent_json_carries_the_image_helper_a_role_declared_in_extra_and_checks_it():
    """In ``extra``, which every agent since pull mode's first reads: an older agent
    refuses an unknown field, and a failed release's converge leaves the older
    agent running with the agent.json that converge wrote."""
    helper = ["/usr/local/lib/x/helper"]
    config = agent_files.Config(robot="robot1", remote="ssh://g@h/fleet", extra={"image_helper": helper})
    written = json.loads(config.to_json())
    assert written["extra"] == {"image_helper": helper} and "image_helper" not in written
    assert agent_files.read_config(config.to_json()) == config and config.image_helper == tuple(helper)
    assert "extra" not in agent_files.Config(robot="robot1", remote="ssh://g@h/fleet").to_json()
    with pytest.raises(agent_files.ConfigError) as caught:
        agent_files.read_config(config.to_json().replace('"/usr/local/lib/x/helper"', "1"), "agent.json")
    assert str(caught.value) == "agent.json: extra.image_helper: expected a command (a list of strings)"
