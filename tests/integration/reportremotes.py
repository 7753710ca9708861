"""A fleet remote and its report shards on this machine (bare git
repositories, file://), robots pushing their reports to them
(transport.Remote), and the sharded fleet the operator's read is tested on:
for tests/integration/test_pull_report_shards.py, test_pull_report_copy.py
and test_pull_stalled_remote.py."""

from __future__ import annotations

import datetime
import subprocess
from pathlib import Path

from robotfleet.pull.protocol import report_shards, reports
from robotfleet.pull.robot import transport
from tests.integration import craftedgit

UTC = datetime.timezone.utc
NOW = datetime.datetime(2026, 11, 25, 10, 0, tzinfo=UTC)
SHARDS = 4


def bare(path: Path) -> Path:
    subprocess.run(["git", "init", "-q", "--bare", "--template=", str(path)], check=True)
    return path


def fleet(tmp_path: Path, shards: int = SHARDS) -> Path:
    """The fleet remote and its report shards (what gitolite creates from its rules)."""
    remote = bare(tmp_path / "fleet.git")
    for shard in range(shards):
        bare(Path(report_shards.shard_url(str(remote), shard)))
    return remote


def report(robot: str, result: str = "applied", when: datetime.datetime = NOW, version: int = 3) -> bytes:
    return reports.to_bytes(
        reports.build(robot, when, result, attempted={"version": version, "result": result, "tries": 1})
    )


def robot_remote(tmp_path: Path, remote: Path, robot: str, shards: int = SHARDS) -> transport.Remote:
    return transport.Remote(
        f"file://{remote}", tmp_path / "robots" / robot, str(tmp_path / "etc"), timeout=60, shards=shards
    )


def sharded_fleet(tmp_path: Path) -> Path:
    """robot1..robot8 reported in their shards; robot9 has not moved (its
    report in the fleet remote); robot2 moved, leaving an older report there."""
    remote = fleet(tmp_path)
    for i in range(1, 9):
        robot = f"robot{i}"
        robot_remote(tmp_path, remote, robot).push_report(robot, report(robot, "failed" if i == 3 else "applied"))
    earlier = NOW - datetime.timedelta(hours=1)
    for robot, result in (("robot9", "applied"), ("robot2", "rolled-back")):
        robot_remote(tmp_path, remote, robot, shards=0).push_report(robot, report(robot, result, earlier))
    return remote


def forge_in_another_shard(tmp_path: Path, remote: Path, robot: str) -> None:
    """A report for ``robot`` pushed into a shard that is not its own (a
    shared enrollment key may write its names in every shard)."""
    other = (report_shards.shard_of(robot, SHARDS) + 1) % SHARDS
    work = craftedgit.workspace(tmp_path / "hostile")
    entry = (
        f"100644 blob {craftedgit.blob(work, report(robot, 'applied', NOW + datetime.timedelta(hours=1)))}\treport.json"
    )
    craftedgit.push_report_entry(Path(report_shards.shard_url(str(remote), other)), work, robot, entry)
