"""Benchmark: reports at ten thousand robots on the lab's gitolite (issue 38,
items 1 and 2).  Prints figures; asserts nothing; not part of the test
command (it starts its own lab's git server, on 127.0.0.1, and takes it down).

    python3 -m tests.bench.reports_scale [--prefix rs] [--sizes 10,1000,10000] [--fleet 10000]
                                         [--minutes 10] [--max-requests 20000] [--workers 16] [--keep]

- report push bytes: one robot force-pushes its report (robotfleet's own
  transport, ssh's count of the bytes both ways) with N report refs on the
  server, N in ``--sizes``, in the single-repository layout and with
  ``pull_report_shards`` = report_shards.suggested(N) (at least 1);
- status read time at ``--fleet`` reports: ``pullstatus.fetch`` (every
  shard fetched concurrently, read with report_store's reader), from an
  empty cache and again warm, in both layouts;
- a later-wave robot's read of the earlier waves' reports (75% of the
  fleet: the last of four waves), fresh and warm, sharded;
- a load generator replaying a ``--fleet``-robot fleet against the server:
  each robot checks every ``--interval`` + up to ``--jitter`` seconds (a
  protocol-v2 fetch of the releases branch, as the agent's idle check) and
  pushes its report at its first check after ``--heartbeat`` seconds (the
  steady state: nothing new), each as that robot with its own key.  It runs
  ``--minutes`` minutes or ``--max-requests`` requests, whichever comes
  first, with ``--workers`` at once, and prints requests per second, the
  server's CPU (its container's cgroup, in cores and as a share of this
  machine's), bytes per hour (ssh's count), and each request's lag behind
  its schedule in the first and the last third of the run (a lag that
  grows is a queue: the server, or this machine, does not keep up).  The
  generator runs on the same machine: its own CPU is printed beside.

Reports are seeded into the server's repositories with ``git fast-import``
as its user (a commit holding a valid report.json per robot), and every
robot is a gitolite user with its own key (rules written by
robotfleet/pull/operator/gitolite.py, as pull-enroll does).
"""

from __future__ import annotations

import argparse
import heapq
import json
import os
import random
import resource
import statistics
import subprocess
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tests.bench import hygiene

RELEASES = "refs/heads/robotfleet/releases"
NAME = "robot-{:05d}"


def keypair() -> tuple[bytes, str]:
    """A robot's key: (private key, OpenSSH format; public key line)."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ed25519

    key = ed25519.Ed25519PrivateKey.generate()
    private = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.OpenSSH,
                                serialization.NoEncryption())
    public = key.public_key().public_bytes(serialization.Encoding.OpenSSH, serialization.PublicFormat.OpenSSH)
    return private, public.decode()


class Server:
    """The lab's gitolite, as its admin and as each robot."""

    def __init__(self, prefix: str, base: Path):
        from robotfleet.pull.operator import gitolite
        from tests.lab import gitserver, state

        lab = state.load(prefix)
        self.git = lab["git"]
        self.admin = gitserver.admin(self.git, lab["ssh_key"])
        self.url = gitserver.local_url(self.git)  # ssh://gitolite3@127.0.0.1:PORT/fleet
        self.base = base
        self.keys: dict[str, tuple[bytes, str]] = {}
        gitolite.GIT_TIMEOUT = 1800  # a gitolite-admin push compiling 10,000 keys takes minutes
        os.environ["GIT_SSH_COMMAND"] = self.admin.env()["GIT_SSH_COMMAND"]  # the operator's reads

    def sh(self, script: str, stdin: bytes | None = None) -> str:
        done = subprocess.run(["docker", "exec", "-i", "-u", "gitolite3", self.git["container"], "sh", "-c", script],
                              input=stdin, capture_output=True, timeout=1800)
        if done.returncode:
            raise SystemExit(f"bench: on the git server: {script[:80]}: {done.stderr.decode()[-500:]}")
        return done.stdout.decode()

    def repo_dir(self, repo: str) -> str:
        return f"/var/lib/gitolite3/repositories/{repo}.git"

    def register(self, robots: list[str], shards: int) -> None:
        """Every robot a gitolite user with its own key; the rules for ``shards``."""
        from robotfleet.pull.operator import gitolite

        for robot in robots:
            self.keys.setdefault(robot, keypair())
        add = {gitolite.key_file(robot): self.keys[robot][1] for robot in robots}
        gitolite.update(self.admin, self.git["repo"], add, message=f"bench: {len(robots)} robots, {shards} shards",
                        shards=shards)

    def seed(self, repo: str, robots: list[str]) -> None:
        """Exactly these robots' reports in ``repo`` (and a releases branch in the fleet's)."""
        from robotfleet.pull.protocol import reports

        where = self.repo_dir(repo)
        self.sh(f"git -C {where} for-each-ref --format='delete %(refname)' refs/reports/ | "
                f"git -C {where} update-ref --stdin")
        stream = []
        moment = int(time.time())
        for index, robot in enumerate(robots):
            data = reports.to_bytes(reports.build(robot, _utc(moment), "up-to-date"))
            stream.append(b"blob\nmark :%d\ndata %d\n%s\n" % (2 * index + 1, len(data), data))
            stream.append(b"commit refs/reports/%s\nmark :%d\ncommitter bench <bench@lab> %d +0000\ndata 6\nreport\n"
                          b"M 100644 :%d report.json\n\n" % (robot.encode(), 2 * index + 2, moment, 2 * index + 1))
        if repo == self.git["repo"]:
            stream.append(b"blob\nmark :999999999\ndata 3\nv1\n\ncommit %s\ncommitter bench <bench@lab> %d +0000\n"
                          b"data 8\nrelease\nM 100644 :999999999 metadata/timestamp.json\n\n"
                          % (RELEASES.encode(), moment))
        self.sh(f"git -C {where} fast-import --quiet --force", stdin=b"".join(stream))

    def cpu_seconds(self) -> float:
        """The server container's CPU time (its cgroup v2's usage)."""
        text = self.sh("cat /sys/fs/cgroup/cpu.stat")
        return int(next(line.split()[1] for line in text.splitlines() if line.startswith("usage_usec"))) / 1e6

    def etc(self, robot: str) -> str:
        """The robot's configuration directory: its key, the server's pinned host key."""
        from robotfleet.pull.protocol import agent_files

        where = self.base / "etc" / robot
        if not where.exists():
            where.mkdir(parents=True)
            key = where / "id_ed25519"
            key.write_bytes(self.keys[robot][0])
            key.chmod(0o600)
            (where / "known_hosts").write_text("".join(f"{agent_files.HOST_KEY_ALIAS} {' '.join(k.split()[:2])}\n"
                                                       for k in self.git["host_keys"]))
        return str(where)

    def remote(self, robot: str, repo: Path, shards: int):
        from robotfleet.pull.robot import transport

        return transport.Remote(self.url, repo, self.etc(robot), timeout=300, shards=shards)


def _utc(seconds: int):
    import datetime

    return datetime.datetime.fromtimestamp(seconds, datetime.timezone.utc)


def layout(server: Server, robots: list[str], shards: int) -> None:
    """The server holding ``robots``' reports in ``shards`` shards (0: in the fleet repository)."""
    from robotfleet.pull.protocol import report_shards

    server.register(robots, shards)
    spread = report_shards.spread(robots, shards)
    server.seed(server.git["repo"], robots if shards == 0 else [])
    for shard in range(shards):
        server.seed(report_shards.shard_repo(server.git["repo"], shard), spread.get(shard, []))


def push_bytes(server: Server, robot: str, shards: int, samples: int = 3) -> dict:
    """One robot's report push: ssh's bytes both ways, and seconds (medians)."""
    from robotfleet.pull.protocol import reports

    found = []
    for index in range(samples):
        hygiene.wait(f"push {shards} shards {index}", first=index == 0, patience=120)
        remote = server.remote(robot, server.base / "robot" / robot, shards)
        remote.push_report(robot, reports.to_bytes(reports.build(robot, _utc(int(time.time())), "up-to-date")))
        push = remote.cost.exchanges[-1]
        found.append({"bytes": push["sent"] + push["received"], "received": push["received"],
                      "seconds": push["seconds"]})
    return {k: statistics.median(f[k] for f in found) for k in ("bytes", "received", "seconds")}


def read_times(server: Server, robots: list[str], shards: int) -> dict:
    """status's read of every report, and a last-wave robot's read of the earlier 75%, fresh then warm."""
    from robotfleet.commands import pullstatus

    figures = {}
    cache = server.base / f"status-{shards}" / "reports"
    for kind in ("fresh", "warm"):
        hygiene.wait(f"status {kind} {shards}", first=kind == "fresh", patience=120)
        started = time.monotonic()
        found = pullstatus.fetch(server.url, cache, shards)
        figures[f"status {kind}"] = round(time.monotonic() - started, 2)
        figures["status reports read"] = sum("error" not in r for r in found.values())
    earlier = robots[: len(robots) * 3 // 4]
    reader = robots[-1]
    for kind in ("fresh", "warm"):
        hygiene.wait(f"wave read {kind} {shards}", first=False, patience=120)
        remote = server.remote(reader, server.base / f"reader-{shards}", shards)
        started = time.monotonic()
        found = remote.fetch_reports(earlier)
        figures[f"wave read {kind}"] = round(time.monotonic() - started, 2)
        figures["wave reports read"] = len(found)
        figures[f"wave read {kind} bytes"] = remote.cost.received + remote.cost.sent
    return figures


def schedule(robots: list[str], interval: int, jitter: int, heartbeat: int, minutes: float, limit: int,
             seed: int = 38) -> list[tuple[float, str, bool]]:
    """(seconds from the start, robot, pushes its report) of each check a
    fleet in its steady state makes in ``minutes``, at most ``limit`` (pure):
    each robot's first check falls anywhere in one interval and jitter, the
    next ones every interval plus up to jitter; its last push anywhere in
    the heartbeat before the start, the next at its first check a heartbeat later."""
    rng = random.Random(seed)
    events: list[tuple[float, str, bool]] = []
    due = [(rng.uniform(0, interval + jitter), robot, -rng.uniform(0, heartbeat)) for robot in robots]
    heapq.heapify(due)
    end = minutes * 60
    while due and len(events) < limit:
        at, robot, pushed = heapq.heappop(due)
        if at > end:
            break
        push = at - pushed >= heartbeat
        events.append((at, robot, push))
        heapq.heappush(due, (at + interval + rng.uniform(0, jitter), robot, at if push else pushed))
    return events


def replay(server: Server, robots: list[str], shards: int, args) -> dict:
    """The load generator: ``schedule`` played against the server in real time."""
    from robotfleet.pull.protocol import reports

    events = schedule(robots, args.interval, args.jitter, args.heartbeat, args.minutes, args.max_requests)
    local = threading.local()
    done: list[dict] = []
    lock = threading.Lock()

    def one(event: tuple[float, str, bool], start: float) -> None:
        at, robot, push = event
        if not hasattr(local, "repo"):
            local.repo = server.base / f"worker-{threading.get_ident()}"
        began = time.monotonic() - start
        remote = server.remote(robot, local.repo, shards)
        ok = True
        try:
            remote.fetch_releases()
            if push:
                remote.push_report(robot, reports.to_bytes(reports.build(robot, _utc(int(time.time())), "up-to-date")))
        except Exception as error:  # counted, not fatal: a refused request is a figure too
            ok = str(error)[:200]
        with lock:
            done.append({"at": at, "lag": began - at, "seconds": time.monotonic() - start - began, "ok": ok,
                         "requests": remote.cost.requests, "bytes": remote.cost.sent + remote.cost.received})

    hygiene.wait("load generator", first=True, patience=300)
    cpu_before, own_before = server.cpu_seconds(), _own_cpu()
    start = time.monotonic()
    with ThreadPoolExecutor(max_workers=args.workers) as pool:
        for event in events:
            time.sleep(max(0.0, event[0] - (time.monotonic() - start)))
            pool.submit(one, event, start)
    wall = time.monotonic() - start
    server_cpu, own_cpu = server.cpu_seconds() - cpu_before, _own_cpu() - own_before
    done.sort(key=lambda d: d["at"])
    third = max(1, len(done) // 3)
    first, last = done[:third], done[-third:]
    failed = [d["ok"] for d in done if d["ok"] is not True]
    requests = sum(d["requests"] for d in done)
    return {"robots": len(robots), "shards": shards, "interval": args.interval, "jitter": args.jitter,
            "heartbeat": args.heartbeat, "seconds": round(wall, 1), "checks": len(done),
            "pushes": sum(e[2] for e in events), "failed": len(failed), "first failure": failed[:1],
            "requests per second": round(requests / wall, 2),
            "server CPU cores": round(server_cpu / wall, 3),
            "server CPU share of this machine": round(server_cpu / wall / (os.cpu_count() or 1), 3),
            "generator CPU cores": round(own_cpu / wall, 3),
            "bytes per hour": round(sum(d["bytes"] for d in done) * 3600 / wall),
            "lag p50/p95 first third": _percentiles(first), "lag p50/p95 last third": _percentiles(last),
            "lag max": round(max((d["lag"] for d in done), default=0), 2)}


def _percentiles(rows: list[dict]) -> list[float]:
    lags = sorted(d["lag"] for d in rows) or [0.0]
    return [round(lags[len(lags) // 2], 2), round(lags[min(len(lags) - 1, int(len(lags) * 0.95))], 2)]


def _own_cpu() -> float:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m tests.bench.reports_scale", description=__doc__.split("\n\n")[0])
    parser.add_argument("--prefix", default="rs")
    parser.add_argument("--sizes", default="10,1000,10000", help="report refs on the server for the push figure")
    parser.add_argument("--fleet", type=int, default=10_000, help="robots for the read times and the load")
    parser.add_argument("--interval", type=int, default=900)
    parser.add_argument("--jitter", type=int, default=300)
    parser.add_argument("--heartbeat", type=int, default=3600)
    parser.add_argument("--minutes", type=float, default=10, help="the load generator's run, at most")
    parser.add_argument("--max-requests", type=int, default=20_000, help="the load generator's checks, at most")
    parser.add_argument("--workers", type=int, default=16, help="the load generator's requests at once")
    parser.add_argument("--keep", action="store_true", help="leave the lab up")
    args = parser.parse_args(argv)
    from robotfleet.pull.protocol import report_shards
    from tests.lab import hosts

    figures: dict = {"push": [], "reads": {}, "load": None}
    try:
        hosts.up(args.prefix, robots=1, laptops=0, git_server=True)
        with tempfile.TemporaryDirectory(prefix="bench-reports-") as base:
            server = Server(args.prefix, Path(base))
            for size in [int(s) for s in args.sizes.split(",")]:
                robots = [NAME.format(i) for i in range(size)]
                for shards in (0, max(1, report_shards.suggested(size))):
                    layout(server, robots, shards)
                    row = {"refs": size, "shards": shards, **push_bytes(server, robots[0], shards)}
                    figures["push"].append(row)
                    print(f"bench: report push at {size} refs, {shards or 'one repository, no'} shards: "
                          f"{json.dumps(row)}", flush=True)
            robots = [NAME.format(i) for i in range(args.fleet)]
            for shards in (0, max(1, report_shards.suggested(args.fleet))):
                layout(server, robots, shards)
                figures["reads"][shards] = read_times(server, robots, shards)
                print(f"bench: reads at {args.fleet} reports, {shards} shards: {json.dumps(figures['reads'][shards])}",
                      flush=True)
            figures["load"] = replay(server, robots, shards, args)
            print(f"bench: load: {json.dumps(figures['load'])}", flush=True)
    finally:
        if not args.keep:
            hosts.down(args.prefix)
    print(json.dumps(figures, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
