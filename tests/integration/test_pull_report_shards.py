"""Reports sharded over several repositories (robotfleet/pull/protocol/report_shards.py)
on real git repositories (file:// remotes): a robot pushes to its own shard
only, a push receives only its shard's refs, the operator reads every shard
(and the fleet remote's reports of robots that have not moved yet), a robot
reads the earlier waves' reports from their shards, and a report is read
only from its own robot's shard."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from robotfleet.commands.pull import status as pullstatus
from robotfleet.pull.protocol import report_shards, report_store, reports
from tests.integration import craftedgit
from tests.integration.reportremotes import (
    NOW,
    SHARDS,
    bare,
    fleet,
    forge_in_another_shard,
    report,
    robot_remote,
    sharded_fleet,
)

# issue 38: a report push moves at most 10 KB whatever the fleet's size; git's part of it
# here, the SSH session's own ~7 KB (both ways, measured on the lab's gitolite:
# docs/explanations/pull.md, "What the git server carries") left for the rest.
PUSH_BUDGET = 10 * 1024 - 7 * 1024
_RECEIVED = re.compile(r"packet: +push< (.*)$")


def refs(repo: Path) -> list[str]:
    return craftedgit.git(repo, "for-each-ref", "--format=%(refname)", "refs/reports/").split()


def test_a_robot_pushes_its_report_to_its_own_shard_and_nowhere_else(tmp_path):
    remote = fleet(tmp_path)
    robot_remote(tmp_path, remote, "robot1").push_report("robot1", report("robot1"))
    own = report_shards.shard_of("robot1", SHARDS)
    for shard in range(SHARDS):
        where = Path(report_shards.shard_url(str(remote), shard))
        assert refs(where) == (["refs/reports/robot1"] if shard == own else []), shard
    assert refs(remote) == []
    assert (
        reports.parse(
            craftedgit.git(
                Path(report_shards.shard_url(str(remote), own)), "show", "refs/reports/robot1:report.json"
            ).encode(),
            "robot1",
        )["result"]
        == "applied"
    )


def test_a_push_the_shard_refuses_goes_to_the_fleet_remote_where_it_was_before(tmp_path):
    """The robot has its new shard count before the server has the shard
    (its rules not rewritten yet): the report still gets through."""
    remote = fleet(tmp_path, shards=0)
    robot_remote(tmp_path, remote, "robot1").push_report("robot1", report("robot1"))
    assert refs(remote) == ["refs/reports/robot1"]


def seed_commit(tmp_path: Path) -> tuple[Path, str]:
    """A repository holding one report commit and no ref (the other
    repositories borrow its objects), and that commit."""
    seed = bare(tmp_path / "seed.git")
    blob = craftedgit.git(seed, "hash-object", "-w", "--stdin", stdin=report("robot0"))
    tree = craftedgit.git(seed, "mktree", stdin=f"100644 blob {blob}\treport.json\n".encode())
    return seed, craftedgit.git(seed, "commit-tree", tree, "-m", "r")


def fill(repo: Path, robots: list[str], seed: tuple[Path, str]) -> None:
    """A report ref for every robot (what a push's advertisement lists), all
    at the seed's commit, its objects borrowed: written as ``git pack-refs``
    writes them (10,000 loose refs would take most of a minute to make)."""
    (repo / "objects" / "info" / "alternates").write_text(f"{seed[0] / 'objects'}\n")
    names = sorted(f"refs/reports/{robot}".encode() for robot in robots)
    (repo / "packed-refs").write_bytes(
        b"# pack-refs with: peeled fully-peeled sorted \n"
        + b"".join(seed[1].encode() + b" " + name + b"\n" for name in names)
    )


def received_by_push(tmp_path: Path, remote: Path, robot: str, shards: int, monkeypatch) -> int:
    """The bytes git's push protocol sent the robot (the ref advertisement
    and the server's answer), from git's packet trace: pkt-line length
    prefix, payload and newline of each packet."""
    trace = tmp_path / f"trace-{shards}"
    monkeypatch.setenv("GIT_TRACE_PACKET", str(trace))
    robot_remote(tmp_path, remote, robot, shards).push_report(robot, report(robot))
    monkeypatch.delenv("GIT_TRACE_PACKET")
    total = 0
    for line in trace.read_text(errors="replace").splitlines():
        match = _RECEIVED.search(line)
        if match:
            payload = match.group(1).replace("\\0", "\0")
            total += 4 if payload == "0000" else 4 + len(payload.encode()) + 1
    trace.unlink()
    return total


def test_a_push_receives_only_its_shard_s_refs_at_ten_thousand_robots(tmp_path, monkeypatch):
    robots = [f"robot{i}" for i in range(10_000)]
    shards = report_shards.suggested(len(robots))
    remote, seed = fleet(tmp_path, 0), seed_commit(tmp_path)
    fill(remote, robots, seed)  # the fleet as one repository holds them all (the layout before)
    own = report_shards.shard_of("robot42", shards)  # the shard it pushes to (the others are never read)
    fill(bare(Path(report_shards.shard_url(str(remote), own))), report_shards.spread(robots, shards)[own], seed)
    before = received_by_push(tmp_path, remote, "robot42", 0, monkeypatch)
    after = received_by_push(tmp_path, remote, "robot42", shards, monkeypatch)
    biggest = max(len(members) for members in report_shards.spread(robots, shards).values())
    assert before > PUSH_BUDGET and after <= PUSH_BUDGET, (
        f"a report push at 10,000 report refs received {before} B from one repository, {after} B from its shard "
        f"(of {shards}, the largest holding {biggest} refs); git's budget is {PUSH_BUDGET} B"
    )
    assert after < before / 50, (before, after)


def test_status_reads_every_shard_and_the_robots_not_moved_yet(tmp_path):
    remote = sharded_fleet(tmp_path)
    forge_in_another_shard(tmp_path, remote, "robot3")
    found = report_store.fetch_every(f"file://{remote}", SHARDS, tmp_path / "cache" / "reports")
    assert sorted(found) == [f"robot{i}" for i in range(1, 10)]
    assert found["robot2"]["result"] == "applied"  # its shard's, newer than what it left in the fleet remote
    assert found["robot9"]["result"] == "applied" and found["robot9"]["time"] == "2026-11-25T09:00:00Z"
    assert found["robot3"]["result"] == "failed"  # the ref another shard holds for it is not its report
    assert sorted(p.name for p in (tmp_path / "cache" / "reports-shards").iterdir()) == [str(s) for s in range(SHARDS)]


def test_status_rows_come_from_the_shards_of_the_fleet_file_s_count(tmp_path, monkeypatch):
    remote = sharded_fleet(tmp_path)
    monkeypatch.setattr(pullstatus, "now", lambda: NOW)
    monkeypatch.setattr(pullstatus.robotfleet, "CHECKOUT", tmp_path)
    data = {"pull_report_shards": SHARDS, "pull_interval": 900, "pull_jitter": 300}
    rows = pullstatus.rows([(f"robot{i}", data) for i in range(1, 11)], f"file://{remote}")
    assert rows["robot3"]["pull"].startswith("failed") and rows["robot1"]["pull"].startswith("applied")
    assert rows["robot10"]["pull"] == "no report"
    assert report_shards.report_url(f"file://{remote}", "robot10", SHARDS) in rows["robot10"]["error"]


def test_a_fleet_file_with_two_shard_counts_is_refused_in_one_line():
    with pytest.raises(
        pullstatus.ReportsUnavailable,
        match="pull_report_shards: robot1 has 0, robot2 has 4: give every pull robot the same",
    ):
        pullstatus.shards_of([("robot1", {}), ("robot2", {"pull_report_shards": 4}), ("robot3", {})])


def test_a_later_wave_robot_reads_the_earlier_waves_from_their_shards(tmp_path):
    remote = sharded_fleet(tmp_path)
    forge_in_another_shard(tmp_path, remote, "robot3")
    reader = robot_remote(tmp_path, remote, "robot10")
    found = reader.fetch_reports([f"robot{i}" for i in range(1, 10)])
    assert sorted(found) == [f"robot{i}" for i in range(1, 10)]
    assert found["robot3"]["result"] == "failed" and reports.failed_for(found["robot3"], 3)
    assert found["robot2"]["result"] == "applied"
    assert found["robot9"]["result"] == "applied"  # not moved: read where it reported before
    touched = {exchange["what"] for exchange in reader.cost.exchanges}
    assert (
        touched == {"reports"}
        and len(reader.cost.exchanges) == len(report_shards.spread([f"robot{i}" for i in range(1, 10)], SHARDS)) + 1
    )  # each shard once, the fleet remote once
    # nothing kept: every fetch checks its objects against every local ref, so
    # refs left by each read made a read of 7,500 reports walk them 256 times
    assert craftedgit.git(reader.repo, "for-each-ref", "--format=%(refname)", "refs/fleet-shards/") == ""
    assert reader.fetch_reports([f"robot{i}" for i in range(1, 10)]) == found  # read again, from what it has


def test_the_agent_reports_to_its_shard_and_halts_on_an_earlier_wave_s_failure_read_from_its_shard(tmp_path):
    from dataclasses import replace

    from tests.integration.pullworld import World
    from tests.unit.pullkit import NOW as RELEASED

    world = World(tmp_path)
    for shard in range(SHARDS):
        bare(Path(report_shards.shard_url(str(world.bare), shard)))
    world.config = replace(world.config, report_shards=SHARDS)
    world.release(3, robots=("robot1", "robot2", "robot3"), canary="2")  # robot2 and robot3 first
    rolled_back = reports.build(
        "robot3", RELEASED, "rolled-back", attempted={"version": 3, "result": "rolled-back", "tries": 1}
    )
    robot_remote(tmp_path, world.bare, "robot3").push_report("robot3", reports.to_bytes(rolled_back))
    _, outcome, sent = world.wake()
    assert (outcome.result, outcome.wave) == ("stopped", 1)
    assert outcome.reason == "wave 1 stopped by the failure budget: 1 robot(s) of the earlier waves failed (budget 0)"
    assert sent == "report sent"
    own = Path(report_shards.shard_url(str(world.bare), report_shards.shard_of("robot1", SHARDS)))
    assert "refs/reports/robot1" in refs(own) and refs(world.bare) == []
