"""Which repository holds a robot's report (robotfleet/pull/protocol/report_shards.py):
every party computes it alike, so it is pinned here, and it spreads a fleet evenly."""

from collections import Counter

import pytest

from robotfleet.pull.protocol import report_shards


def test_a_robot_s_shard_is_pinned_by_its_name_and_the_count():
    # Pinned values: a change here moves every robot of every sharded fleet
    # to another repository, where the server's rules do not let it write.
    assert report_shards.shard_of("robot1", 16) == 14
    assert report_shards.shard_of("robot1", 128) == 94
    assert report_shards.shard_of("r.1", 7) == 3
    assert report_shards.shard_of("robot1", 0) is None
    assert all(report_shards.shard_of(f"robot{i}", 1) == 0 for i in range(50))


@pytest.mark.parametrize(
    "names",
    [
        [f"robot{i}" for i in range(1, 10_001)],
        [f"robot-{(i * 2654435761) % (1 << 48):012x}" for i in range(10_000)],  # machine-id names
    ],
    ids=["numbered", "machine-id"],
)
def test_ten_thousand_robots_spread_over_256_shards_evenly(names):
    counts = Counter(report_shards.shard_of(name, 256) for name in names)
    assert len(counts) == 256
    # 39 a shard on average; none holds more than ~60 refs (~5 KB of a push's advertisement)
    assert 20 <= min(counts.values()) and max(counts.values()) <= 62, (min(counts.values()), max(counts.values()))


@pytest.mark.parametrize(
    "url, shard, expected",
    [
        ("ssh://gitolite3@git.lan/fleet", 3, "ssh://gitolite3@git.lan/fleet-reports-3"),
        ("ssh://gitolite3@git.lan:2222/fleets/a/", 0, "ssh://gitolite3@git.lan:2222/fleets/a-reports-0"),
        ("gitolite3@git.lan:fleet.git", 12, "gitolite3@git.lan:fleet-reports-12.git"),
        ("https://mirror.lan/fleet.git", 5, "https://mirror.lan/fleet-reports-5.git"),
        ("file:///srv/fleet.git", 1, "file:///srv/fleet-reports-1.git"),
        ("ssh://gitolite3@git.lan/fleet", None, "ssh://gitolite3@git.lan/fleet"),
    ],
)
def test_a_shard_s_url_is_the_fleet_remote_s_beside_it(url, shard, expected):
    assert report_shards.shard_url(url, shard) == expected


def test_a_shard_s_gitolite_repository_matches_its_url():
    assert report_shards.shard_repo("fleet", 7) == "fleet-reports-7"
    assert report_shards.shard_repo("fleet", None) == "fleet"
    assert report_shards.report_url("ssh://g@h/fleet", "robot1", 16) == "ssh://g@h/fleet-reports-14"
    assert report_shards.report_url("ssh://g@h/fleet", "robot1", 0) == "ssh://g@h/fleet"


def test_robots_are_grouped_by_shard():
    spread = report_shards.spread(["robot3", "robot1", "robot2", "robot1"], 4)
    assert sorted(r for robots in spread.values() for r in robots) == ["robot1", "robot2", "robot3"]
    assert all(report_shards.shard_of(r, 4) == shard for shard, robots in spread.items() for r in robots)
    assert report_shards.spread(["b", "a"], 0) == {None: ["a", "b"]}


@pytest.mark.parametrize(
    "robots, count", [(10, 0), (16, 0), (17, 2), (1_000, 64), (10_000, 1024), (100_000, 4096), (10**7, 4096)]
)
def test_the_suggested_count_keeps_sixteen_refs_a_shard_or_fewer(robots, count):
    assert report_shards.suggested(robots) == count


@pytest.mark.parametrize("count", [-1, 4097, True, "8", 2.0])
def test_a_count_that_cannot_be_used_is_one_line(count):
    with pytest.raises(report_shards.ShardError, match=r"pull_report_shards: expected a whole number from 0 to 4096"):
        report_shards.shard_of("robot1", count)


def test_the_agent_configuration_carries_the_shard_count():
    import json

    from robotfleet.pull.protocol import agent_files

    config = agent_files.Config(robot="robot1", remote="ssh://g@h/fleet", report_shards=128)
    assert agent_files.read_config(config.to_json()).report_shards == 128
    single = agent_files.Config(robot="robot1", remote="ssh://g@h/fleet")
    assert "report_shards" not in json.loads(single.to_json())  # an agent from before shards reads it too
    assert agent_files.read_config(single.to_json()).report_shards == 0
    raw = {**json.loads(single.to_json()), "report_shards": 5000}
    with pytest.raises(
        agent_files.ConfigError, match=r"agent.json: report_shards: expected a whole number from 0 to 4096, got 5000"
    ):
        agent_files.read_config(json.dumps(raw), "agent.json")


def test_the_server_s_copy_hook_keeps_the_readers_size_limit_and_ref():
    """files/git-server/post-receive is shell: what it shares with the readers is checked here."""
    import re

    import robotfleet
    from robotfleet.pull.protocol import report_store, reports

    hook = (robotfleet.CHECKOUT / "files" / "git-server" / "post-receive").read_text()
    assert re.search(r"^MAX_BYTES=(\d+) ", hook, re.M).group(1) == str(reports.MAX_BYTES)
    assert re.search(r"^COPY=(\S+)$", hook, re.M).group(1) == report_store.COPY
