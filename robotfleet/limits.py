"""The operator process sized for a run of N hosts: its open-file limit,
raised to what the run needs, and its garbage collector, run less often.

pyinfra keeps one SSH connection open per host for the whole run, and
sizes its pool to a third of the soft limit (``(RLIMIT_NOFILE - 10) / 3``),
so a run of N hosts wants about 3 N descriptors.  The soft limit (often
1024) is raised up to the hard one, which any process may do; where the
hard limit is lower than the run needs, one line says so."""

from __future__ import annotations

import gc
import resource

PER_HOST = 3  # pyinfra's own reckoning (pyinfra.api.state.MAX_PARALLEL)
SPARE = 64  # the process's own files: Python, logs, the fleet file, known_hosts
# pyinfra plans every operation of every host before it runs one, and keeps
# what it planned: Python's default (a young-generation collection every 700
# new objects) walked that heap some 2,000 times in a no-op of 1,000 hosts,
# ~8 % of its CPU (tests/bench/SCALE.md); every 50,000 costs a few MB.
COLLECT_EVERY = 50_000


def needed(hosts: int) -> int:
    return PER_HOST * hosts + SPARE


def raise_open_files(hosts: int) -> str | None:
    """Raise the soft limit to what ``hosts`` hosts need (never lower it,
    never above the hard limit); the line to print when the hard limit is
    too low, else None."""
    want = needed(hosts)
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < want:
        new = want if hard == resource.RLIM_INFINITY else min(want, hard)
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (new, hard))
        except (ValueError, OSError):
            return None  # left as it was: pyinfra's pool follows the soft limit
        soft = new
    if soft != resource.RLIM_INFINITY and soft < want:
        return (
            f"{hosts} hosts need about {want} open files and this process may have at most {hard} "
            f"(ulimit -Hn): raise the hard limit (limits.conf, systemd's LimitNOFILE) or run fewer hosts "
            f"at once (--limit a group, robotfleet rollout)"
        )
    return None


def collect_less_often() -> None:
    """Raise the collector's first threshold to COLLECT_EVERY (never lower it)."""
    young, middle, old = gc.get_threshold()
    if 0 < young < COLLECT_EVERY:
        gc.set_threshold(COLLECT_EVERY, middle, old)
