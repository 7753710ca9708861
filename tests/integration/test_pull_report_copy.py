"""The git server's read copy of the sharded reports (files/git-server/post-receive,
run by real git as each repository's post-receive hook; file:// remotes):
each report pushed to a shard lands at <shard>/<robot> of one commit in the
fleet remote, status and a later-wave robot read that one ref instead of
every shard, and each report is still read only from its own robot's shard."""

from __future__ import annotations

import datetime
import os
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import robotfleet
from robotfleet.pull.protocol import report_shards, report_store, reports
from robotfleet.pull.robot import transport
from tests.integration import craftedgit
from tests.integration.reportremotes import (
    NOW,
    SHARDS,
    fleet,
    forge_in_another_shard,
    report,
    robot_remote,
    sharded_fleet,
)

HOOK = robotfleet.CHECKOUT / "files" / "git-server" / "post-receive"


def shard_dir(remote: Path, shard: int) -> Path:
    return Path(report_shards.shard_url(str(remote), shard))


def install(remote: Path) -> None:
    """The hook in every repository, as gitolite links its common hooks into each."""
    for repo in [remote, *(shard_dir(remote, shard) for shard in range(SHARDS))]:
        (repo / "hooks").mkdir(exist_ok=True)
        shutil.copy(HOOK, repo / "hooks" / "post-receive")


def copied(remote: Path) -> dict[str, str]:
    """<shard>/<robot> -> the report.json held there, in the fleet remote's copy."""
    listed = craftedgit.git(remote, "ls-tree", "-r", "--name-only", report_store.COPY).split()
    return {path: craftedgit.git(remote, "cat-file", "blob", f"{report_store.COPY}:{path}") for path in listed}


def path_of(robot: str) -> str:
    return f"{report_shards.shard_of(robot, SHARDS)}/{robot}"


def copied_fleet(tmp_path: Path) -> Path:
    """sharded_fleet's reports (robot3's forged in another shard too), pushed with the hook in place."""
    install(fleet(tmp_path))
    remote = sharded_fleet(tmp_path)  # the same repositories (git init again changes nothing)
    forge_in_another_shard(tmp_path, remote, "robot3")
    return remote


def test_each_report_pushed_to_a_shard_lands_in_the_copy_at_its_shard_s_path(tmp_path):
    remote = copied_fleet(tmp_path)
    found = copied(remote)
    for i in range(1, 9):
        robot = f"robot{i}"
        pushed = craftedgit.git(
            shard_dir(remote, report_shards.shard_of(robot, SHARDS)), "show", f"refs/reports/{robot}:report.json"
        )
        assert found[path_of(robot)] == pushed
    forged = f"{(report_shards.shard_of('robot3', SHARDS) + 1) % SHARDS}/robot3"
    assert forged in found  # copied where it was pushed: the readers' shard check leaves it out
    assert "robot9" not in {path.split("/")[1] for path in found}  # pushed to the fleet remote itself: not a shard's
    parents = craftedgit.git(remote, "rev-list", "--parents", "-n1", report_store.COPY).split()
    assert len(parents) == 1  # no history: old copies are garbage


def test_status_reads_the_copy_alone_and_each_report_only_from_its_own_shard(tmp_path):
    remote = copied_fleet(tmp_path)
    cache = tmp_path / "cache" / "reports"
    found = report_store.fetch_every(f"file://{remote}", SHARDS, cache)
    assert sorted(found) == [f"robot{i}" for i in range(1, 10)]
    assert found["robot3"]["result"] == "failed"  # the forged one, under another shard's path, is not its report
    assert found["robot2"]["result"] == "applied"  # its shard's, newer than what it left in the fleet remote
    assert found["robot9"]["time"] == "2026-11-25T09:00:00Z"  # not moved: the fleet remote's
    assert not (tmp_path / "cache" / "reports-shards").exists()  # no shard fetched


def test_a_later_wave_robot_reads_the_copy_in_one_exchange_and_again_from_what_it_kept(tmp_path):
    remote = copied_fleet(tmp_path)
    reader = robot_remote(tmp_path, remote, "robot10")
    wanted = [f"robot{i}" for i in range(1, 10)]
    found = reader.fetch_reports(wanted)
    assert sorted(found) == wanted and found["robot3"]["result"] == "failed"
    assert found["robot2"]["result"] == "applied" and found["robot9"]["result"] == "applied"
    assert len(reader.cost.exchanges) == 1
    robot_remote(tmp_path, remote, "robot4").push_report("robot4", report("robot4", "rolled-back", NOW))
    again = reader.fetch_reports(wanted)
    assert again["robot4"]["result"] == "rolled-back" and len(reader.cost.exchanges) == 2
    assert reader.fetch_reports(["robot1"]) == {"robot1": found["robot1"]}


def test_a_reader_falls_back_to_the_shards_when_the_server_drops_its_copy(tmp_path):
    remote = copied_fleet(tmp_path)
    reader = robot_remote(tmp_path, remote, "robot10")
    reader.fetch_reports(["robot1"])
    for shard in range(SHARDS):
        (shard_dir(remote, shard) / "hooks" / "post-receive").unlink()
    craftedgit.git(remote, "update-ref", "-d", report_store.COPY)
    robot_remote(tmp_path, remote, "robot1").push_report("robot1", report("robot1", "failed", NOW))
    assert reader.fetch_reports(["robot1"])["robot1"]["result"] == "failed"
    assert craftedgit.git(reader.repo, "for-each-ref", transport.COPY) == ""


def test_seed_builds_the_copy_from_the_shards_already_there(tmp_path):
    remote = sharded_fleet(tmp_path)  # pushed before the hook was installed
    install(remote)
    done = subprocess.run(["sh", str(HOOK), "--seed", str(remote)], capture_output=True, text=True, check=True)
    assert f"from {SHARDS} report shard(s)" in done.stdout
    assert sorted(copied(remote)) == sorted(path_of(f"robot{i}") for i in range(1, 9))
    with_copy = report_store.fetch_every(f"file://{remote}", SHARDS, tmp_path / "a" / "reports")
    assert not (tmp_path / "a" / "reports-shards").exists()
    craftedgit.git(remote, "update-ref", "-d", report_store.COPY)
    assert report_store.fetch_every(f"file://{remote}", SHARDS, tmp_path / "b" / "reports") == with_copy


def test_what_is_not_one_robot_s_bounded_report_is_not_copied_and_a_deleted_ref_leaves(tmp_path):
    remote = fleet(tmp_path)
    install(remote)
    robot_remote(tmp_path, remote, "robot1").push_report("robot1", report("robot1"))
    shard = shard_dir(remote, report_shards.shard_of("robot1", SHARDS))
    work = craftedgit.workspace(tmp_path / "hostile")
    big = craftedgit.blob(work, b"x" * (reports.MAX_BYTES + 1))
    for ref in ("refs/reports/robot2", "refs/reports/team/robot5", "refs/reports/-dash"):
        craftedgit.push_report_entry(shard, work, ref.removeprefix("refs/reports/"), f"100644 blob {big}\treport.json")
    assert list(copied(remote)) == [path_of("robot1")]  # too big, a path, not a name: none copied
    craftedgit.git(work, "push", "-q", str(shard), ":refs/reports/robot1")
    assert craftedgit.git(remote, "ls-tree", report_store.COPY) == ""


def test_reports_pushed_at_once_all_land_in_the_copy(tmp_path):
    remote = fleet(tmp_path)
    install(remote)
    robots = [f"robot{i}" for i in range(16)]
    with ThreadPoolExecutor(max_workers=8) as pool:
        list(pool.map(lambda r: robot_remote(tmp_path, remote, r).push_report(r, report(r)), robots))
    assert sorted(copied(remote)) == sorted(path_of(robot) for robot in robots)
    assert all(reports.parse(data.encode(), path.split("/")[1]) for path, data in copied(remote).items())


def test_the_copy_keeps_the_newest_push_of_each_robot(tmp_path):
    remote = fleet(tmp_path)
    install(remote)
    robot = robot_remote(tmp_path, remote, "robot1")
    for hour, result in enumerate(("applied", "failed", "up-to-date")):
        robot.push_report("robot1", report("robot1", result, NOW + datetime.timedelta(hours=hour)))
    assert reports.parse(copied(remote)[path_of("robot1")].encode(), "robot1")["result"] == "up-to-date"


def test_a_robot_reads_the_copy_from_a_static_https_mirror_of_the_fleet_remote(tmp_path):
    """A mirror made as docs/guides/pull-from-nothing.md step 9 says carries the
    copy with the rest: a robot reading from it needs no shard there."""
    from tests.integration import httpsgit

    remote = copied_fleet(tmp_path)
    mirror = tmp_path / "www" / "fleet.git"
    subprocess.run(["git", "clone", "-q", "--mirror", str(remote), str(mirror)], check=True)
    craftedgit.git(mirror, "update-server-info")
    ca, cert, key = httpsgit.make_ca(tmp_path / "tls")
    server = httpsgit.Server(tmp_path / "www", cert, key, smart=False)
    try:
        etc = tmp_path / "mirror-etc"
        etc.mkdir()
        (etc / "remote-ca.pem").write_bytes(ca.read_bytes())
        reader = transport.Remote(server.url("fleet.git"), tmp_path / "reader", str(etc), timeout=60, shards=SHARDS)
        found = reader.fetch_reports([f"robot{i}" for i in range(1, 10)])
    finally:
        server.close()
    assert sorted(found) == [f"robot{i}" for i in range(1, 10)]
    assert found["robot3"]["result"] == "failed" and found["robot9"]["result"] == "applied"
    assert len(reader.cost.exchanges) == 1


def test_a_copy_changed_behind_the_hook_is_read_again_before_the_next_push(tmp_path):
    """The hook keeps its index between pushes; a copy seeded or rewritten by
    anything else is what the next push adds to, not the hook's old index."""
    remote = fleet(tmp_path)
    install(remote)
    robot_remote(tmp_path, remote, "robot1").push_report("robot1", report("robot1"))
    craftedgit.git(remote, "update-ref", "-d", report_store.COPY)
    robot_remote(tmp_path, remote, "robot2").push_report("robot2", report("robot2"))
    assert list(copied(remote)) == [path_of("robot2")]  # started again: robot1's entry was only in the index
    subprocess.run(["sh", str(HOOK), "--seed", str(remote)], capture_output=True, check=True)
    robot_remote(tmp_path, remote, "robot3").push_report("robot3", report("robot3"))
    assert sorted(copied(remote)) == sorted(path_of(f"robot{i}") for i in (1, 2, 3))


def test_a_copy_path_the_hook_never_writes_is_not_read(tmp_path):
    """Paths only an admin's hand could put in the copy (a deeper path, a
    non-ASCII digit) are not read as any robot's report."""
    remote = fleet(tmp_path)
    install(remote)
    robot_remote(tmp_path, remote, "robot1").push_report("robot1", report("robot1"))
    listed = craftedgit.git(remote, "ls-tree", "-r", report_store.COPY)
    blob = listed.split()[2]
    # each would pass the shard check were it read as a path of the hook's kind
    deep = next(f"robot9/{i}" for i in range(100) if report_shards.shard_of(f"robot9/{i}", SHARDS) == 0)
    third = next(f"robot{i}" for i in range(2, 100) if report_shards.shard_of(f"robot{i}", SHARDS) == 3)
    odd = [f"0/{deep}", f"\u0663/{third}"]  # a path deeper than <shard>/<robot>; an Arabic-Indic 3
    env = {**os.environ, "GIT_INDEX_FILE": str(tmp_path / "odd.index")}

    def index(*args: str) -> str:
        return subprocess.run(
            ["git", "-C", str(remote), *args], env=env, check=True, capture_output=True, text=True
        ).stdout

    index("read-tree", report_store.COPY)
    for path in odd:
        index("update-index", "--add", "--cacheinfo", f"100644,{blob},{path}")
    tree = index("write-tree").strip()
    craftedgit.git(remote, "update-ref", report_store.COPY, craftedgit.git(remote, "commit-tree", tree, "-m", "odd"))
    found = report_store.fetch_every(f"file://{remote}", SHARDS, tmp_path / "cache" / "reports")
    assert sorted(found) == ["robot1"]
