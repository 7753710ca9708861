"""Benchmark: reports at ten thousand robots on the lab's gitolite (issue 38,
item 1).  Prints figures; asserts nothing; not part of the test command (it
starts only its own lab's git server, on 127.0.0.1, and takes it down).

    python3 -m tests.bench.reports_scale [--prefix rs] [--sizes 10,1000,10000] [--fleet 10000]
        [--single] [--without-copy] [--keep]

- report push bytes: one robot of the fullest repository force-pushes its
  report (robotfleet's own transport, ssh's count of the bytes both ways,
  median of ``--samples``; the robot pins the server's ed25519 key, as the
  guides do) with N report refs on the server, N in ``--sizes``, in the
  layout ``pull_report_shards`` = report_shards.suggested(N) gives (and with
  ``--single``, also in the single repository);
- status's read at ``--fleet`` reports: ``pullstatus.fetch`` (the fleet
  remote and its read copy of every shard, kept by the server's hook; with
  ``--without-copy``, also every shard fetched, eight at once), from an
  empty cache and again warm;
- a later-wave robot's read of the earlier waves' reports (75% of the
  fleet: the last of four waves), fresh and warm, the same ways.

The fleet is tests/bench/gitolite_fleet.py's: every robot a gitolite user
with its own key, its report seeded with ``git fast-import``.  Each figure
waits for an idle machine first (hygiene.py) and carries the 1-minute load
it started at.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from tests.bench import gitolite_fleet, hygiene
from tests.bench.gitolite_fleet import Server


def push_bytes(server: Server, robot: str, shards: int, samples: int) -> dict:
    """One robot's report push: ssh's bytes both ways, and seconds (medians)."""
    found, loads = [], []
    for index in range(samples):
        loads.append(hygiene.wait(f"push {shards} shards {index}", first=index == 0)[0])
        remote = server.remote(robot, server.base / "robot" / robot, shards)
        remote.push_report(robot, gitolite_fleet.report(robot))
        push = remote.cost.exchanges[-1]
        found.append(
            {
                "bytes": push["sent"] + push["received"],
                "sent": push["sent"],
                "received": push["received"],
                "seconds": push["seconds"],
            }
        )
    figures = {k: statistics.median(f[k] for f in found) for k in ("bytes", "sent", "received", "seconds")}
    return {**figures, "load": max(loads)}


def read_times(server: Server, names: list[str], shards: int, how: str) -> dict:
    """status's read of every report, and a last-wave robot's read of the earlier 75%, fresh then warm."""
    from robotfleet.commands.pull import status as pullstatus

    figures: dict = {}
    cache = server.base / f"status-{shards}-{how}" / "reports"
    for kind in ("fresh", "warm"):
        figures[f"status {kind} load"] = hygiene.wait(f"status {kind} {shards}", first=kind == "fresh")[0]
        started = time.monotonic()
        found = pullstatus.fetch(server.url, cache, shards)
        figures[f"status {kind} seconds"] = round(time.monotonic() - started, 2)
        figures["status reports read"] = sum("error" not in r for r in found.values())
    earlier = names[: len(names) * 3 // 4]
    reader = names[-1]
    remote = server.remote(reader, server.base / f"reader-{shards}-{how}", shards)
    for kind in ("fresh", "warm"):
        figures[f"wave read {kind} load"] = hygiene.wait(f"wave read {kind} {shards}", first=False)[0]
        before = remote.cost.sent + remote.cost.received, remote.cost.requests
        started = time.monotonic()
        found = remote.fetch_reports(earlier)
        figures[f"wave read {kind} seconds"] = round(time.monotonic() - started, 2)
        figures["wave reports read"] = sum("error" not in r for r in found.values())
        figures[f"wave read {kind} bytes"] = remote.cost.sent + remote.cost.received - before[0]
        figures[f"wave read {kind} sessions"] = remote.cost.requests - before[1]
    return figures


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m tests.bench.reports_scale", description=__doc__.split("\n\n")[0])
    parser.add_argument("--prefix", default="rs", help="the lab's name (only its git server is started)")
    parser.add_argument("--sizes", default="10,1000,10000", help="report refs on the server for the push figure")
    parser.add_argument("--fleet", type=int, default=10_000, help="reports on the server for the read times (0: none)")
    parser.add_argument("--samples", type=int, default=3, help="pushes per figure (the median is printed)")
    parser.add_argument("--single", action="store_true", help="the push figure in the single repository too")
    parser.add_argument("--without-copy", action="store_true", help="the reads over every shard too")
    parser.add_argument("--keep", action="store_true", help="leave the git server up")
    args = parser.parse_args(argv)
    from robotfleet.pull.protocol import report_shards
    from tests.lab import hosts

    figures: dict = {"push": [], "reads": {}}
    try:
        with tempfile.TemporaryDirectory(prefix="bench-reports-") as base:
            server = Server(args.prefix, Path(base))
            sizes = [int(s) for s in args.sizes.split(",") if s]
            # the reads where the pushes left that layout: each new layout of a
            # big fleet is a gitolite compile of every key (minutes at 10,000)
            for size in sorted(set(sizes) | ({args.fleet} if args.fleet else set())):
                names = gitolite_fleet.robots(size)
                suggested = report_shards.suggested(size)
                for shards in ([0] if args.single or not suggested else []) + ([suggested] if suggested else []):
                    server.layout(names, shards)
                    if size in sizes:  # a robot of the fullest repository: the largest advertisement
                        fullest = max(report_shards.spread(names, shards).values(), key=len)
                        row = {
                            "refs": size,
                            "shards": shards,
                            "refs in its repository": len(fullest),
                            **push_bytes(server, fullest[0], shards, args.samples),
                        }
                        figures["push"].append(row)
                        print(
                            f"bench: report push at {size} refs, {shards or 'no'} shards: {json.dumps(row)}", flush=True
                        )
                    if size == args.fleet and shards == suggested:
                        ways = ["copy"] if shards else ["single"]
                        for how in ways + (["shards"] if shards and args.without_copy else []):
                            if how == "shards":
                                server.drop_copy()
                            figures["reads"][how] = read_times(server, names, shards, how)
                            print(
                                f"bench: reads at {size} reports, {shards} shards ({how}): "
                                f"{json.dumps(figures['reads'][how])}",
                                flush=True,
                            )
    finally:
        if not args.keep:
            hosts.down(args.prefix)
    print(json.dumps(figures, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
