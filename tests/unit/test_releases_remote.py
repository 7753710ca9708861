"""The fleet's releases remote, named once (issue 39 item 2): --remote, else
the checkout's git config robotfleet.remote, else the one remote the pull
robots name; never the deploy repository's origin by default."""

from __future__ import annotations

import pytest

from robotfleet.pull.operator import releases_remote as rr

ROBOTS = [
    (
        "robot1",
        {
            "pull_enabled": True,
            "pull_remote": "https://mirror/fleet.git",
            "pull_report_remote": "ssh://git@server/fleet",
        },
    ),
    ("robot2", {"pull_enabled": True, "pull_remote": "https://mirror/fleet.git"}),
    ("robot3", {"pull_enabled": False, "pull_remote": "ssh://elsewhere/x"}),
]


def test_the_pull_robots_name_their_remote_and_push_robots_name_none():
    assert rr.named_by(ROBOTS) == ["https://mirror/fleet.git"]
    assert rr.named_by(ROBOTS, reports=True) == ["ssh://git@server/fleet", "https://mirror/fleet.git"]
    assert rr.named_by([("robot3", {"pull_remote": "ssh://elsewhere/x"})]) == []


def test_given_then_configured_then_the_fleet_s_one_remote():
    assert rr.choose("ssh://given/x", "ssh://config/x", ["https://fleet/x"]) == "ssh://given/x"
    assert rr.choose(None, "ssh://config/x", ["https://fleet/x"]) == "ssh://config/x"
    assert rr.choose(None, None, ["https://fleet/x"]) == "https://fleet/x"


def test_nothing_named_or_two_remotes_is_one_line_saying_how_to_name_it():
    with pytest.raises(
        rr.Unnamed,
        match=r"^no releases remote is named .*name it once: git config robotfleet"
        r"\.remote URL in the checkout .*or give --remote URL\.$",
    ):
        rr.choose(None, None, [])
    with pytest.raises(rr.Unnamed, match=r"^the pull robots name 2 remotes \(https://a/x, https://b/x\); say which "):
        rr.choose(None, None, ["https://a/x", "https://b/x"])
    with pytest.raises(rr.Unnamed, match=r"the fleet file could not be read: f\.yaml: robot1\.pull_enabled: expected"):
        rr.choose(None, None, [], "f.yaml: robot1.pull_enabled: expected true or false")
