"""A medium left mounted does not override the network (robotfleet/pull/robot/agent.py
fetch and verify, robotfleet/pull/robot/verify.py newest): with
``pull_media_dir`` holding a valid release and the fleet remote reachable,
the agent fetches the remote too, verifies both from the same trust and
takes the newer signed release; a halt published over the network reaches
a robot whose stale stick is still in, a newer release on the network is
applied from the network, and a medium newer than a lagging remote is
applied from the medium (its images loaded).  The same real TUF
repositories, bare remote and recording `docker` as test_pull_media.py."""

from __future__ import annotations

import pytest

from robotfleet.pull.operator import publishing
from robotfleet.pull.protocol import agent_files
from tests.integration.mediaworld import MediaWorld, loads
from tests.integration.pullworld import World
from tests.unit.pullkit import NOW


@pytest.fixture
def world(tmp_path, image_registry):
    return MediaWorld(tmp_path, image_registry[0])


def reachable(robot) -> None:
    robot.config = agent_files.Config(**{**robot.config.__dict__, "remote": f"file://{robot.bare}"})


def test_a_halt_published_over_the_network_reaches_a_robot_whose_stale_stick_is_mounted(world, docker):
    world.release(1)  # exported to the stick, which stays in
    halted = publishing.halt(world.fleet.repository, world.fleet.keys, "canary crash-loops", world.fleet.expiry, NOW)
    world.push()  # the halt on the fleet remote only
    reachable(world)
    _, outcome, sent = world.wake()
    assert (outcome.result, outcome.reason) == ("halted", f"release {halted.version} is a halt: canary crash-loops")
    assert loads(docker) == []  # release 1 was not applied from the stick
    assert sent == "report sent" and world.pushed_report()["result"] == "halted"
    # a newer release on the network only: applied from there, nothing loaded from the stick
    World.release(world, 3)
    _, outcome, _ = world.wake()
    assert (outcome.result, outcome.reason) == ("applied", "release 3 applied"), outcome.reason
    assert loads(docker) == []
    _, outcome, _ = world.wake()
    assert outcome.result == "up-to-date", outcome.reason


def test_the_same_release_on_both_is_applied_from_the_medium_and_a_newer_medium_beats_a_lagging_remote(world, docker):
    world.release(1)
    world.push()  # the network has release 1 too (export writes its metadata back)
    reachable(world)
    _, outcome, sent = world.wake()
    assert (outcome.result, outcome.reason) == ("applied", "release 1 applied"), outcome.reason
    assert len(loads(docker)) == 1 and sent == "report sent"  # its images from the medium
    world.release(2)  # exported to the stick only; the remote still serves release 1
    _, outcome, _ = world.wake()
    assert (outcome.result, outcome.reason) == ("applied", "release 2 applied"), outcome.reason
    _, outcome, _ = world.wake()  # the remote's older metadata is not a refusal while the medium is newer
    assert outcome.result == "up-to-date", outcome.reason
