"""Benchmark: pull mode on the lab.  Prints figures; asserts nothing; not
part of the test command (it builds its own lab of N robots).

    python3 -m tests.bench.pull [--prefix pb] [--robots 10] [--intervals 30,60] [--jitters 0,15]
                                [--runs 3] [--idle-samples 5] [--no-write] [--write-loaded] [--keep]

Writes the pull-mode section of tests/bench/RESULTS.md (and RESULTS-pull.json)
when every figure started on an idle machine (tests/bench/sections.py).

- publish -> 50% / 100% of the robots healthy on the new release, the
  robots woken only by their timers (pull_interval, pull_jitter), for each
  interval x jitter (each setting reaches the robots as a release first);
- an idle check on one robot: wall seconds, CPU seconds (the agent and
  everything it ran, from its journal line), bytes sent and received over
  SSH (ssh's own count), with and without a report push;
- bytes per update: what a robot's applying wake moved (its journal line);
- a 10,000-robot fleet's load on the git server per hour, computed from the
  measured per-check cost (bytes and git requests of an idle check, and of
  one that pushes its report) and printed with its formula: checks, report
  pushes, git requests (ssh sessions; HTTP requests over HTTPS) and bytes per
  hour; each push also receives the ref advertisement of every robot's
  report ref (~64 bytes a robot), which the measurement on a small lab
  holds for its own robots only, so it is scaled to the fleet.

The lab: `--robots` robots and the git server, provisioned by push, then the
pull agent installed (as tests/e2e/test_pull.py does).  Figures wait for an
idle machine (tests/bench/hygiene.py) and say when they could not.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from tests.bench import hygiene, sections

ROOT = Path(__file__).resolve().parents[2]
LINE = re.compile(
    r"robot-pull: (?P<result>[a-z-]+)(?: \(release (?P<version>\d+)\))?.*; (?P<seconds>[\d.]+) s, "
    r"(?P<cpu>[\d.]+) s CPU, sent (?P<sent>\d+) B, received (?P<received>\d+) B"
    r"(?: in (?P<requests>\d+) requests)?; (?P<report>.*?)(?: \[(?P<phases>[^\]]*)\])?$"
)
FLEET_SIZE = 10_000
COST = ("seconds", "cpu", "sent", "received", "requests")
# bytes per report ref a push receives (pkt-line: 4 + 40-hex oid + space + refs/reports/<name> + LF)
REF_ADVERTISEMENT = 64


def phases(line: dict) -> dict[str, float]:
    """A journal line's phases ("verify 0.31 s, deploy 4.20 s") as {name: seconds} (pure)."""
    found = {}
    for part in (line.get("phases") or "").split(", "):
        name, _, rest = part.rpartition(" ")[0].rpartition(" ")
        if name and rest:
            found[name] = float(rest)
    return found


def run_conditions(robots: int, **more) -> dict:
    """A section's conditions: when, at which commit, on how many CPUs and robots, and ``more``."""
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "commit": commit.stdout.strip(),
        "cpus": os.cpu_count(),
        "robots": robots,
        **more,
    }


def journal(lab, robot: str) -> list[dict]:
    code, out = lab.sh(robot, "journalctl -u robot-pull.service -o cat --no-pager | grep '^robot-pull: '")
    return [m.groupdict() for m in map(LINE.match, out.splitlines()) if m]


class Lab:
    def __init__(self, prefix: str):
        from tests.lab import state

        self.prefix = prefix
        self.state = state.load(prefix)
        self.robots = [h["name"] for h in self.state["hosts"] if h["group"] == "robots"]

    def sh(self, host: str, command: str) -> tuple[int, str]:
        from tests.lab.state import exec_in

        return exec_in(self.prefix, host, command)

    def trigger(self, robots) -> None:
        threads = [threading.Thread(target=self.sh, args=(r, "systemctl start robot-pull.service")) for r in robots]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()


def setup(prefix: str, robots: int, base: Path):
    """The lab (N robots, no laptop, the git server), provisioned by push, the agent installed."""
    from tests.lab import hosts, pullfleet

    hosts.up(prefix, robots=robots, laptops=0, git_server=True)
    env = dict(os.environ, ROBOT_LAB_PREFIX=prefix, PYINFRA_PROGRESS="off")
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "pyinfra", "-y", "inventories/lab.py", "deploy.py"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    if done.returncode:
        raise SystemExit(f"bench: the fresh provisioning failed: {done.stderr[-2000:]}")
    print(f"bench: {robots} robots provisioned by push in {time.monotonic() - started:.0f} s", flush=True)
    op = pullfleet.Operator(prefix, base)
    op.setup()
    op.publish(pullfleet.fleet_text(op.lab), "release 1", "--pause", "0")
    fleet = str(op.repo / pullfleet.FLEET)
    done = subprocess.run(
        [sys.executable, "-m", "pyinfra", "-y", "inventories/lab.py", "deploy.py"],
        cwd=ROOT,
        env={**op.env(ROBOT_LAB_FLEET=fleet), "PYINFRA_PROGRESS": "off"},
        capture_output=True,
        text=True,
    )
    if done.returncode:
        raise SystemExit(f"bench: installing the agent failed: {done.stderr[-2000:]}")
    op.robotfleet(
        "pull-enroll",
        "inventories/lab.py",
        "--ssh",
        *op.admin_options(),
        *op.remote(),
        env=op.env(ROBOT_LAB_FLEET=fleet),
    )
    lab = Lab(prefix)
    lab.trigger(lab.robots)
    return op, lab


def idle_check(lab, op, samples: int) -> dict:
    """Median cost of a check that finds nothing new, on the first robot:
    without a report push, and with one (its heartbeat made due)."""
    robot = lab.robots[0]
    lab.trigger([robot])
    lab.trigger([robot])  # settled: the report says nothing new
    found = {"without a report push": [], "with a report push": []}
    for index in range(samples * 2):
        if index % 2:  # a heartbeat: the report is pushed although nothing changed
            lab.sh(
                robot,
                "python3 -c \"import json; p='/var/lib/robot-pull/agent-state.json'; "
                "s=json.load(open(p)); s.pop('reported', None); json.dump(s, open(p, 'w'))\"",
            )
        load, idle = hygiene.wait(f"idle check {index}", first=index == 0, patience=120)
        lab.trigger([robot])
        line = journal(lab, robot)[-1]
        kind = "with a report push" if line["report"].startswith("report sent") else "without a report push"
        found[kind].append({**{k: float(line[k] or 0) for k in COST}, "load": load, "idle": idle})
    return {kind: summary(samples_) for kind, samples_ in found.items() if samples_}


def summary(samples: list[dict]) -> dict:
    """The median of each cost, the CPU seconds' spread, the samples and whether all started idle (pure)."""
    return {
        **{k: statistics.median(s[k] for s in samples) for k in COST},
        "cpu_min": min(s["cpu"] for s in samples),
        "cpu_max": max(s["cpu"] for s in samples),
        "samples": len(samples),
        "idle": all(s["idle"] for s in samples),
        "load": max(s["load"] for s in samples),
    }


def rollout_times(lab, op, interval: int, jitter: int, tag: str, staged: bool = False) -> dict:
    """Publish, then the time until 50% and 100% of the robots report the
    release applied and healthy.  All robots in one wave, or ``staged``: with
    publish's default plan (a canary, then the rest once its pause, the
    robots' longest interval + jitter, has passed)."""
    from tests.lab import pullfleet

    settings = {"pull_interval": interval, "pull_jitter": jitter, "pull_boot_delay": 5}
    op.publish(
        pullfleet.fleet_text(op.lab, payload_tag="1.0" if tag == "1.1" else "1.1", **settings),
        f"timers {interval}/{jitter}",
        "--pause",
        "0",
        "--no-wheels",
    )
    lab.trigger(lab.robots)  # the new timers in place (and that release applied)
    load, idle = hygiene.wait(f"rollout {interval}/{jitter}", first=True, patience=300)
    published = time.monotonic()
    done = op.publish(
        pullfleet.fleet_text(op.lab, payload_tag=tag, **settings),
        f"bench {tag}",
        "--no-wheels",
        *(() if staged else ("--canary", "100%", "--pause", "0")),
    )
    version = int(re.search(r"release (\d+)", done.stdout).group(1))
    reached: dict[str, float] = {}
    deadline = published + 10 * (interval + jitter) + 300
    while len(reached) < len(lab.robots) and time.monotonic() < deadline:
        for robot, report in op.reports().items():
            if (
                robot in lab.robots
                and robot not in reached
                and (report.get("applied") or {}).get("version", 0) >= version
                and (report.get("status") or {}).get("health") == "healthy"
            ):
                reached[robot] = time.monotonic() - published
        time.sleep(1)
    times = sorted(reached.values())
    half = times[(len(lab.robots) + 1) // 2 - 1] if len(times) >= (len(lab.robots) + 1) // 2 else None
    updates = [
        line
        for robot in lab.robots
        for line in journal(lab, robot)
        if line["result"] == "applied" and line["version"] == str(version)
    ]
    applies = [float(u["seconds"]) for u in updates]
    return {
        "interval": interval,
        "jitter": jitter,
        "staged": staged,
        "robots": len(lab.robots),
        "reached": len(times),
        "longest_apply": max(applies) if applies else None,
        "to_50%": half,
        "to_100%": times[-1] if len(times) == len(lab.robots) else None,
        "bytes_per_update": (
            statistics.median(int(u["sent"]) + int(u["received"]) for u in updates) if updates else None
        ),
        "load": load,
        "idle": idle,
    }


def target_of(sample: dict) -> float | None:
    """Issue 38 item 5: every robot applied within twice (interval + jitter)
    plus one apply (the run's longest), pure."""
    if sample.get("longest_apply") is None:
        return None
    return 2 * (sample["interval"] + sample["jitter"]) + sample["longest_apply"]


def within_target(sample: dict) -> bool:
    target = target_of(sample)
    return target is not None and sample["to_100%"] is not None and sample["to_100%"] <= target


def rollout_figure(samples: list[dict]) -> dict:
    """Samples of one interval x jitter: median and spread of the times to
    50% and 100% (None when a sample did not get there), pure."""

    def spread(key: str) -> dict | None:
        values = [s[key] for s in samples]
        if not values or None in values:
            return None
        return {"median": statistics.median(values), "min": min(values), "max": max(values)}

    first = samples[0]
    updates = [s["bytes_per_update"] for s in samples if s["bytes_per_update"] is not None]
    return {
        "interval": first["interval"],
        "jitter": first["jitter"],
        "staged": first.get("staged", False),
        "within_target": all(within_target(s) for s in samples),
        "robots": first["robots"],
        "samples": len(samples),
        "reached": min(s["reached"] for s in samples),
        "to_50%": spread("to_50%"),
        "to_100%": spread("to_100%"),
        "bytes_per_update": statistics.median(updates) if updates else None,
        "idle": all(s["idle"] for s in samples),
        "load": max(s["load"] for s in samples),
        "runs": samples,
    }


def fleet_per_hour(
    idle: dict, interval: int, jitter: int, heartbeat: int = 3600, robots_measured: int = 1, fleet: int = FLEET_SIZE
) -> dict:
    """What ``fleet`` robots ask of the git server per hour at this interval
    and jitter, from one robot's measured check cost (pure).

    Each robot checks every interval + jitter/2 (+ the check's own time) on
    average; a check pushes its report only at its first check after the
    heartbeat (nothing new: the steady state), so pushes per robot per hour
    are 3600 / (heartbeat + the wait for that check, half a period on
    average), at most one per check.  A push's extra bytes over an idle
    check hold the advertisement of its repository's report refs: scaled
    from ``robots_measured`` (one repository) to the refs of one of the
    shards ``report_shards.suggested`` gives ``fleet`` robots."""
    from robotfleet.pull.protocol import report_shards

    plain = idle.get("without a report push") or {}
    pushed = idle.get("with a report push") or plain
    period = interval + jitter / 2
    checks = fleet * 3600 / (period + plain.get("seconds", 0))
    pushes = min(checks, fleet * 3600 / (heartbeat + period / 2))
    idle_bytes = plain.get("sent", 0) + plain.get("received", 0)
    push_extra = pushed.get("sent", 0) + pushed.get("received", 0) - idle_bytes
    shards = report_shards.suggested(fleet)
    push_extra += REF_ADVERTISEMENT * (math.ceil(fleet / max(1, shards)) - robots_measured)
    requests = checks * plain.get("requests", 0) + pushes * (pushed.get("requests", 0) - plain.get("requests", 0))
    per_hour = checks * idle_bytes + pushes * push_extra
    return {
        "robots": fleet,
        "interval": interval,
        "jitter": jitter,
        "heartbeat": heartbeat,
        "checks_per_hour": round(checks),
        "report_pushes_per_hour": round(pushes),
        "git_requests_per_hour": round(requests),
        "git_requests_per_second": round(requests / 3600, 1),
        "bytes_per_hour": round(per_hour),
        "megabits_per_second": round(per_hour * 8 / 3600 / 1e6, 2),
        "formula": (
            "checks = N*3600/(interval + jitter/2 + check s); pushes = min(checks, N*3600/(heartbeat + (interval "
            "+ jitter/2)/2)); requests = checks*(idle check requests) + pushes*(push requests - idle requests); "
            f"bytes = checks*(idle check bytes) + pushes*(push bytes - idle bytes + {REF_ADVERTISEMENT}*(N/shards - "
            "robots measured) advertised report refs, shards = report_shards.suggested(N))"
        ),
    }


def print_fleet(rows: list[dict]) -> None:
    for row in rows:
        print(
            f"bench: {row['robots']} robots, interval {row['interval']} s, jitter {row['jitter']} s, heartbeat "
            f"{row['heartbeat']} s: {row['checks_per_hour']} checks and {row['report_pushes_per_hour']} report "
            f"pushes an hour, {row['git_requests_per_hour']} git requests ({row['git_requests_per_second']}/s), "
            f"{row['bytes_per_hour'] / 1e9:.2f} GB ({row['megabits_per_second']} Mbit/s)",
            flush=True,
        )
    if rows:
        print(f"bench: {rows[0]['formula']}", flush=True)


def spread_text(figure: dict | None) -> str:
    if not figure:
        return "-"
    return f"{figure['median']:.1f} ({figure['min']:.1f}–{figure['max']:.1f})"


def loaded(figure: dict) -> str:
    return "" if figure.get("idle") else f" [load {figure['load']:.1f}]"


def markdown(figures: dict, conditions: dict) -> str:
    """The pull-mode section of RESULTS.md (pure)."""
    n = figures["robots"]
    lines = [
        "## Pull mode (issue 26)",
        "",
        "Written by `python3 -m tests.bench.pull`: its own lab of N robots and the git server, the agent "
        "installed by push and each robot enrolled; seconds unless said otherwise.  A figure whose sample did "
        "not start idle carries `[load X]`.",
        "",
    ]
    lines += [f"- {k}: {v}" for k, v in conditions.items()]
    lines += [
        "",
        f"Publish -> robots healthy on the new release, N={n}, each robot woken only by its timer "
        "(median (min–max) of the runs; `pull_boot_delay` 5 s):",
        "",
        "| pull_interval / pull_jitter | 50% healthy | 100% healthy | bytes per update, one robot | runs |",
        "|---|---|---|---|---|",
    ]
    for row in figures.get("rollouts", []):
        update = f"{row['bytes_per_update']:,.0f}" if row.get("bytes_per_update") is not None else "-"
        lines.append(
            f"| {row['interval']} s / {row['jitter']} s | {spread_text(row['to_50%'])} | "
            f"{spread_text(row['to_100%'])}{loaded(row)} | {update} | {row['samples']} |"
        )
    staged = figures.get("staged")
    if staged:
        lines += [
            "",
            "Publish with the plan a user gets (no option: one canary, then the rest once the pause, the "
            "robots' longest `pull_interval` + `pull_jitter`, has passed), the timers 900 s / 300 s of the "
            f"role's defaults compressed to {staged['interval']} s / {staged['jitter']} s (the pause "
            f"{staged['interval'] + staged['jitter']} s).  Target (issue 38 item 5): every robot applied "
            "within 2 x (interval + jitter) + one apply (the run's longest applying wake):",
            "",
            "| run | 50% healthy | 100% healthy | longest apply | target | met |",
            "|---|---|---|---|---|---|",
        ]
        for index, run in enumerate(staged["runs"], 1):
            target = target_of(run)
            lines.append(
                f"| {index} | {run['to_50%'] or 0:.1f} | "
                + (f"{run['to_100%']:.1f}" if run["to_100%"] is not None else f"{run['reached']} robots")
                + f"{loaded(run)} | {run['longest_apply'] or 0:.1f} | "
                + (f"{target:.1f}" if target is not None else "-")
                + f" | {'yes' if within_target(run) else '**no**'} |"
            )
    lines += [
        "",
        "An idle check on one robot (a wake that finds nothing new; median of its samples; CPU: the "
        "agent and every program it ran, from its journal line; bytes: its git transport's):",
        "",
        "| check | wall | CPU (min–max) | bytes sent | bytes received | git requests | samples |",
        "|---|---|---|---|---|---|---|",
    ]
    for kind, cost in figures.get("idle_check", {}).items():
        lines.append(
            f"| {kind} | {cost['seconds']:.2f} | {cost['cpu']:.2f} ({cost['cpu_min']:.2f}–"
            f"{cost['cpu_max']:.2f}){loaded(cost)} | {cost['sent']:,.0f} | {cost['received']:,.0f} | "
            f"{cost['requests']:.0f} | {cost['samples']} |"
        )
    rows = figures.get("fleet_per_hour", [])
    if rows:
        lines += [
            "",
            f"What a {rows[0]['robots']:,}-robot fleet asks of its git server per hour, computed from "
            "the idle checks above (not measured at that size):",
            "",
            "| interval / jitter / heartbeat | checks | report pushes | git requests (per s) | bytes (Mbit/s) |",
            "|---|---|---|---|---|",
        ]
        for row in rows:
            lines.append(
                f"| {row['interval']} s / {row['jitter']} s / {row['heartbeat']} s | "
                f"{row['checks_per_hour']:,} | {row['report_pushes_per_hour']:,} | "
                f"{row['git_requests_per_hour']:,} ({row['git_requests_per_second']}) | "
                f"{row['bytes_per_hour'] / 1e9:.2f} GB ({row['megabits_per_second']}) |"
            )
        lines += ["", f"Formula: {rows[0]['formula']}."]
    return "\n".join(lines) + "\n"


def all_idle(figures: dict) -> bool:
    found = [*figures.get("idle_check", {}).values(), *figures.get("rollouts", []), figures.get("staged") or {}]
    return all(f.get("idle", True) for f in found)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m tests.bench.pull", description=__doc__.split("\n\n")[0])
    parser.add_argument("--prefix", default="pb")
    parser.add_argument("--robots", type=int, default=10)
    parser.add_argument("--intervals", default="30,60")
    parser.add_argument("--jitters", default="0,15")
    parser.add_argument("--runs", type=int, default=3, help="rollouts per interval x jitter")
    parser.add_argument(
        "--staged-runs", type=int, default=3, help="rollouts with publish's default plan (a canary, then the rest)"
    )
    parser.add_argument(
        "--staged-timers",
        default="60/20",
        metavar="INTERVAL/JITTER",
        help="their timers (default 60/20: the role's 900/300 divided by 15)",
    )
    parser.add_argument("--idle-samples", type=int, default=5)
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--write-loaded", action="store_true", help="write even figures taken under load (marked)")
    parser.add_argument("--keep", action="store_true", help="leave the lab up")
    args = parser.parse_args(argv)
    from tests.lab import hosts

    figures = {"robots": args.robots}
    try:
        with tempfile.TemporaryDirectory(prefix="bench-pull-") as base:
            op, lab = setup(args.prefix, args.robots, Path(base))
            figures["idle_check"] = idle_check(lab, op, args.idle_samples)
            print(f"bench: idle check: {json.dumps(figures['idle_check'])}", flush=True)
            figures["fleet_per_hour"] = [
                fleet_per_hour(figures["idle_check"], i, j, robots_measured=len(lab.robots))
                for i, j in ((300, 60), (900, 300), (3600, 600))
            ]
            print_fleet(figures["fleet_per_hour"])
            figures["rollouts"] = []
            tag = "1.1"
            for interval in [int(i) for i in args.intervals.split(",")]:
                for jitter in [int(j) for j in args.jitters.split(",")]:
                    samples = []
                    for _ in range(args.runs):
                        samples.append(rollout_times(lab, op, interval, jitter, tag))
                        print(f"bench: publish -> healthy: {json.dumps(samples[-1])}", flush=True)
                        tag = "1.0" if tag == "1.1" else "1.1"
                    if samples:
                        figures["rollouts"].append(rollout_figure(samples))
            interval, jitter = (int(v) for v in args.staged_timers.split("/"))
            samples = []
            for _ in range(args.staged_runs):
                samples.append(rollout_times(lab, op, interval, jitter, tag, staged=True))
                print(f"bench: staged publish -> healthy: {json.dumps(samples[-1])}", flush=True)
                tag = "1.0" if tag == "1.1" else "1.1"
            if samples:
                figures["staged"] = rollout_figure(samples)
    finally:
        if not args.keep:
            hosts.down(args.prefix)
    conditions = run_conditions(args.robots, **{"load limit before each figure (1 min)": hygiene.LIMIT})
    text = markdown(figures, conditions)
    print(json.dumps(figures, indent=2))
    print(text)
    if args.no_write:
        return 0
    if not all_idle(figures) and not args.write_loaded:
        print(
            "[bench] not written: some samples did not start idle (see [load X]); rerun on an idle machine, "
            "or pass --write-loaded",
            file=sys.stderr,
        )
        return 1
    sections.write("pull", text, {"conditions": conditions, "figures": figures})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
