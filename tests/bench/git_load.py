"""Benchmark: the load a pull fleet puts on one git server (issue 38, item 2).
Prints figures; asserts nothing; not part of the test command (it starts
only its own lab's git server, on 127.0.0.1, and takes it down).

    python3 -m tests.bench.git_load [--prefix gl] [--fleet 10000] [--speed 1] [--minutes 10] [--workers 32]
        [--checks ssh|https]

A generator replays a ``--fleet``-robot fleet in its steady state against
the lab's gitolite (tests/bench/gitolite_fleet.py: every robot a gitolite
user with its own key and its report on the server, sharded as
``report_shards.suggested`` says unless ``--shards``): each robot checks
every ``--interval`` plus up to ``--jitter`` seconds (the agent's idle
check: robotfleet's transport fetching the releases branch as that robot,
a protocol-v2 fetch of one branch) and pushes its report at its first check
a ``--heartbeat`` after its last push (nothing changes in the steady state).
Each robot's history is played from two hours and more before the start,
so the replay starts in the steady state, pushes included.

With ``--checks https`` the checks go to a static copy of the fleet remote
that the git server's own nginx serves over TLS (tests/bench/https_mirror.py),
each the agent's one conditional request, and the reports to gitolite over
SSH as ``pull_report_remote`` sends them: the layout docs/explanations/pull.md
gives 10,000 robots.  The server's CPU counts both.

Time compression: ``--speed s`` plays the schedule s times faster, so the
server sees the request rate of a fleet of ``fleet x s`` robots in real
time (what differs is only how many report refs each shard holds: the
fleet's, not ``fleet x s``'s).  Every rate printed is per second or hour of
the wall clock, i.e. of that equivalent fleet.

It runs ``--minutes`` of wall time or ``--max-requests`` checks, whichever
ends first, at most ``--workers`` checks at once, and prints: the checks a
second the schedule offered, and checks and git sessions (requests) a
second over the run (its last checks' completion included), the server's
CPU (its container's cgroup, in cores and as a share of the machine's two:
the target is at most half), its CPU per session, bytes per hour both ways
(ssh's count), failed checks, and each check's lag behind its schedule and
its duration in the first and the last third of the run.  A server that
keeps up shows the same lag and duration in both; a queue shows them
growing.  The generator runs on the same machine: its own CPU (its ssh and
git included) is printed beside, and the 1-minute load before the run.
"""

from __future__ import annotations

import argparse
import heapq
import json
import os
import random
import resource
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tests.bench import gitolite_fleet, https_mirror, hygiene
from tests.bench.gitolite_fleet import Server


def schedule(
    robots: list[str], interval: int, jitter: int, heartbeat: int, minutes: float, limit: int, seed: int = 38
) -> list[tuple[float, str, bool]]:
    """(seconds from the start, robot, pushes its report) of each check a
    fleet in its steady state makes in ``minutes``, at most ``limit`` (pure):
    each robot checks every interval plus up to jitter, and pushes at its
    first check a heartbeat after its last push.  Each robot's history is
    played from two heartbeats and intervals before the start (its first
    check anywhere in one interval and jitter there, its last push anywhere
    in one push cycle before that), so the replay opens in the steady state:
    a start with each last push anywhere in the hour before made a 10-minute
    run push a third as often."""
    rng = random.Random(seed)
    events: list[tuple[float, str, bool]] = []
    warm, cycle = 2 * (heartbeat + interval + jitter), heartbeat + (interval + jitter) / 2
    due = []
    for robot in robots:
        first = rng.uniform(0, interval + jitter) - warm
        due.append((first, robot, first - rng.uniform(0, cycle)))  # its pushes' phase anywhere in one cycle
    heapq.heapify(due)
    end = minutes * 60
    while due and len(events) < limit:
        at, robot, pushed = heapq.heappop(due)
        if at > end:
            break
        push = at - pushed >= heartbeat
        if at >= 0:
            events.append((at, robot, push))
        heapq.heappush(due, (at + interval + rng.uniform(0, jitter), robot, at if push else pushed))
    return events


def summary(done: list[dict], wall: float, server_cpu: float, own_cpu: float, cpus: int) -> dict:
    """The run's figures from each check's row (pure)."""
    done = sorted(done, key=lambda d: d["at"])
    third = max(1, len(done) // 3)
    first, last = done[:third], done[-third:]
    failed = [d["ok"] for d in done if d["ok"] is not True]
    sessions = sum(d["requests"] for d in done)
    return {
        "seconds": round(wall, 1),
        "checks": len(done),
        "pushes": sum(d["push"] for d in done),
        "failed": len(failed),
        "first failure": failed[:1],
        "checks per second": round(len(done) / wall, 2),
        "sessions per second": round(sessions / wall, 2),
        "server CPU cores": round(server_cpu / wall, 3),
        "server CPU share of the machine": round(server_cpu / wall / cpus, 3),
        "server CPU ms per session": round(1000 * server_cpu / max(1, sessions), 1),
        "generator CPU cores": round(own_cpu / wall, 3),
        "bytes per hour": round(sum(d["bytes"] for d in done) * 3600 / wall),
        "lag p50/p95 first third": _percentiles(first, "lag"),
        "lag p50/p95 last third": _percentiles(last, "lag"),
        "duration p50/p95 first third": _percentiles(first, "seconds"),
        "duration p50/p95 last third": _percentiles(last, "seconds"),
        "lag max": round(max((d["lag"] for d in done), default=0), 2),
    }


def _percentiles(rows: list[dict], key: str) -> list[float]:
    values = sorted(d[key] for d in rows) or [0.0]
    return [round(values[len(values) // 2], 3), round(values[min(len(values) - 1, int(len(values) * 0.95))], 3)]


def replay(server: Server, names: list[str], shards: int, args, mirror=None) -> dict:
    """``schedule`` played against the server at ``args.speed`` times real time
    (the checks against ``mirror``, https_mirror.py, when given)."""
    events = schedule(names, args.interval, args.jitter, args.heartbeat, args.minutes * args.speed, args.max_requests)
    local = threading.local()
    done: list[dict] = []
    lock = threading.Lock()

    def one(event: tuple[float, str, bool], start: float) -> None:
        at, robot, push = event
        if not hasattr(local, "repo"):
            local.repo = server.base / f"worker-{threading.get_ident()}"
        began = time.monotonic() - start
        remote = server.remote(robot, local.repo, shards, mirror)
        ok: bool | str = True
        try:
            remote.fetch_releases()
            if push:
                remote.push_report(robot, gitolite_fleet.report(robot))
        except Exception as error:  # counted, not fatal: a refused request is a figure too
            ok = str(error)[:200]
        with lock:
            done.append(
                {
                    "at": at / args.speed,
                    "lag": began - at / args.speed,
                    "push": push,
                    "ok": ok,
                    "seconds": time.monotonic() - start - began,
                    "requests": remote.cost.requests,
                    "bytes": remote.cost.sent + remote.cost.received,
                }
            )

    load = hygiene.wait("load generator", first=True)[0]
    cpu_before, own_before = server.cpu_seconds(), _own_cpu()
    start = time.monotonic()
    with ThreadPoolExecutor(max_workers=args.workers) as pool:
        for event in events:
            time.sleep(max(0.0, event[0] / args.speed - (time.monotonic() - start)))
            pool.submit(one, event, start)
    wall = time.monotonic() - start
    server_cpu, own_cpu = server.cpu_seconds() - cpu_before, _own_cpu() - own_before
    span = max(1.0, events[-1][0] / args.speed) if events else 1.0
    return {
        "fleet": len(names),
        "speed": args.speed,
        "as a fleet of": len(names) * args.speed,
        "shards": shards,
        "checks over": "https" if mirror else "ssh",
        "interval": args.interval,
        "jitter": args.jitter,
        "heartbeat": args.heartbeat,
        "workers": args.workers,
        "load before": load,
        "offered checks per second": round(len(events) / span, 2),
        **summary(done, wall, server_cpu, own_cpu, os.cpu_count() or 1),
        "load after": round(hygiene.load(), 2),
    }


def _own_cpu() -> float:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m tests.bench.git_load", description=__doc__.split("\n\n")[0])
    parser.add_argument("--prefix", default="gl", help="the lab's name (only its git server is started)")
    parser.add_argument("--fleet", type=int, default=10_000, help="robots replayed")
    parser.add_argument("--shards", type=int, default=None, help="pull_report_shards (default: suggested)")
    parser.add_argument("--interval", type=int, default=900)
    parser.add_argument("--jitter", type=int, default=300)
    parser.add_argument("--heartbeat", type=int, default=3600)
    parser.add_argument("--speed", type=float, default=1.0, help="the schedule played this many times faster")
    parser.add_argument("--minutes", type=float, default=10, help="the run's wall time, at most")
    parser.add_argument("--max-requests", type=int, default=20_000, help="checks, at most")
    parser.add_argument("--workers", type=int, default=32, help="checks at once, at most")
    parser.add_argument(
        "--checks",
        choices=("ssh", "https"),
        default="ssh",
        help="https: the idle checks from a static copy the git server's nginx serves, the reports over SSH",
    )
    parser.add_argument("--keep", action="store_true", help="leave the git server up")
    args = parser.parse_args(argv)
    from robotfleet.pull.protocol import report_shards
    from tests.lab import hosts

    shards = report_shards.suggested(args.fleet) if args.shards is None else report_shards.check_count(args.shards)
    try:
        with tempfile.TemporaryDirectory(prefix="bench-load-") as base:
            server = Server(args.prefix, Path(base))
            names = gitolite_fleet.robots(args.fleet)
            server.layout(names, shards)
            mirror = https_mirror.ensure(server, gitolite_fleet.REPOSITORIES) if args.checks == "https" else None
            figures = replay(server, names, shards, args, mirror)
    finally:
        if not args.keep:
            hosts.down(args.prefix)
    print(f"bench: load: {json.dumps(figures, indent=2)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
