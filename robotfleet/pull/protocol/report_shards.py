"""Which repository holds a robot's report: the reports are sharded over
several repositories beside the fleet remote, so that a report push, which
first receives every ref of its repository (git's push protocol has no v2
and no ref filter), receives only its shard's (~64 bytes a ref).

Every party computes a robot's shard the same way, from its name and the
fleet's shard count (``pull_report_shards``, carried in the agent's
configuration): the robot that pushes, a robot reading the earlier waves'
reports, the operator's status, rollout and pull-enroll, and gitolite's
rules.  Pure: no host, no process.

- ``count`` 0 is the single-repository layout: ``refs/reports/<robot>`` of
  the fleet remote itself (fleets from before sharding, and small ones).
- ``count`` n > 0: shard ``sha256(robot name) mod n`` (the first 8 bytes,
  big-endian) holds ``refs/reports/<robot>`` in the repository named as the
  fleet remote with ``-reports-<shard>`` (``ssh://g@h/fleet`` ->
  ``ssh://g@h/fleet-reports-3``; ``fleet.git`` -> ``fleet-reports-3.git``).
- A report is read only from its robot's own shard (or the fleet remote,
  for the single-repository layout): a ref another shard holds for that
  name is not its report.
"""

from __future__ import annotations

import hashlib
import math

SINGLE = 0  # the reports in the fleet remote itself
MAX_SHARDS = 4096
# ~70 bytes a ref: a push's advertisement of ~1 KB (~1.5 KB in the fullest
# shard), beside the ~7 KB of its SSH session (docs/explanations/pull.md); the
# readers pay nothing for many shards once the server keeps their read copy.
REFS_PER_SHARD = 16


class ShardError(ValueError):
    """A shard count that cannot be used (one line)."""


def check_count(count, where: str = "pull_report_shards") -> int:
    if isinstance(count, bool) or not isinstance(count, int) or not 0 <= count <= MAX_SHARDS:
        raise ShardError(f"{where}: expected a whole number from 0 to {MAX_SHARDS}, got {count!r}")
    return count


def shard_of(robot: str, count: int) -> int | None:
    """The shard of ``robot`` among ``count``; None for the single repository."""
    if check_count(count) == SINGLE:
        return None
    return int.from_bytes(hashlib.sha256(robot.encode()).digest()[:8], "big") % count


def _suffixed(location: str, shard: int) -> str:
    base = location.rstrip("/")
    git = base.endswith(".git")
    return f"{base.removesuffix('.git')}-reports-{shard}{'.git' if git else ''}"


def shard_url(url: str, shard: int | None) -> str:
    """The git URL of report shard ``shard`` of the fleet remote ``url``
    (``url`` itself for None: the single repository)."""
    return url if shard is None else _suffixed(url, shard)


def shard_repo(repo: str, shard: int | None) -> str:
    """The gitolite repository of shard ``shard`` of the fleet repository ``repo``."""
    return repo if shard is None else _suffixed(repo, shard)


def report_url(url: str, robot: str, count: int) -> str:
    """Where ``robot`` pushes its report (``url``: the fleet remote or the report remote)."""
    return shard_url(url, shard_of(robot, count))


def spread(robots, count: int) -> dict[int | None, list[str]]:
    """shard -> its robots, sorted (one key, None, for the single repository)."""
    found: dict[int | None, list[str]] = {}
    for robot in sorted(set(robots)):
        found.setdefault(shard_of(robot, count), []).append(robot)
    return found


def suggested(robots: int) -> int:
    """A shard count for a fleet of ``robots``: the power of two that keeps
    each shard at ~REFS_PER_SHARD refs or fewer on average (0, the single
    repository, up to that many robots)."""
    if robots <= REFS_PER_SHARD:
        return SINGLE
    return min(MAX_SHARDS, 1 << math.ceil(math.log2(math.ceil(robots / REFS_PER_SHARD))))
