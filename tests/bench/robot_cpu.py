"""What a command costs a lab robot in CPU, program by program.

    python3 -m tests.bench.robot_cpu [--prefix perf] [--host robot1] [--runs 10] [--rounds 4] [--snapshot] [COMMAND ...]

Runs each COMMAND (default: `sudo true`; `--snapshot` adds the host's
snapshot command, captured from a no-op run of deploy.py) over SSH on one
robot of a running lab, ``runs`` times in each of ``rounds`` rounds (the
commands alternating, so a drift of the machine's speed falls on all
alike; each command's figure against the first's printed), while the kernel's scheduler
tracepoints are recorded on this machine (`perf record -a`: fork, exec and
the CPU time each task gets; root, and a kernel with these tracepoints).
Every task that descends from the robot container's own processes (its
sshd, systemd, logind, dbus, dockerd, containerd, ...) is counted under the
program it runs; the rest of the machine is left out.  Each command's figure
is CPU per run, the robot's background over the same time taken away (an
idle window of the same length, recorded the same way).  The container's
cgroup count (all of it, in one number) is printed beside it.

CPU time is what the robot pays whatever else the machine runs, so these
figures hold up on a busy machine better than wall time does (the load is
printed with them: on a loaded machine caches and frequency make every
program somewhat dearer).  Nothing here is a test: it asserts nothing.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from tests.bench import sections
from tests.bench.profile import HERE, ROOT, cgroup_cpu_ns

EVENTS = ("sched:sched_process_fork", "sched:sched_process_exec", "sched:sched_stat_runtime")
_FORK = re.compile(r"sched_process_fork: comm=.* pid=(\d+) child_comm=.* child_pid=(\d+)")
_EXEC = re.compile(r"sched_process_exec: filename=(\S+) pid=(\d+)")
_RUNTIME = re.compile(r"sched_stat_runtime: comm=.* pid=(\d+) runtime=(\d+)")


@dataclass
class Cost:
    """CPU a robot spent on one command, per run."""

    seconds: float  # the command's own processes plus the daemons' extra work, background taken away
    programs: dict[str, tuple[float, float]] = field(default_factory=dict)  # name -> (starts, seconds) per run
    cgroup: float | None = None  # the container's whole count per run, background included
    load: float = 0.0


def container_tasks(container: str) -> dict[int, str]:
    """Host thread id -> command name of every task in the container's cgroup."""
    cid = subprocess.run(
        ["docker", "inspect", "-f", "{{.Id}}", container], capture_output=True, text=True, check=True
    ).stdout.strip()
    for path in (
        f"/sys/fs/cgroup/cpuacct/docker/{cid}/tasks",
        f"/sys/fs/cgroup/system.slice/docker-{cid}.scope/cgroup.threads",
    ):
        if os.path.exists(path):
            tids = [int(line) for line in Path(path).read_text().split()]
            break
    else:
        raise SystemExit(f"robot_cpu: no cgroup found for {container}")
    names = {}
    for tid in tids:
        try:
            names[tid] = Path(f"/proc/{tid}/comm").read_text().strip()
        except OSError:
            continue
    return names


def attribute(lines, roots: dict[int, str]) -> dict[str, list[float]]:
    """From `perf script` lines: program -> [starts, CPU seconds] of every
    task descending from ``roots`` (tid -> name).  A task counts under the
    last program it (or the parent it was forked from) executed; the
    container's own daemons count under their names plus " (daemon)"."""
    name = {tid: f"{comm} (daemon)" for tid, comm in roots.items()}
    found: dict[str, list[float]] = collections.defaultdict(lambda: [0, 0.0])
    for line in lines:
        if "sched_process_fork" in line:
            match = _FORK.search(line)
            if match and int(match.group(1)) in name:
                parent, child = int(match.group(1)), int(match.group(2))
                name[child] = name[parent]
        elif "sched_process_exec" in line:
            match = _EXEC.search(line)
            if match and int(match.group(2)) in name:
                program = os.path.basename(match.group(1))
                if program.isdigit():  # fexecve(): systemd runs its executor from a file descriptor
                    program = "systemd-executor (from a descriptor)"
                name[int(match.group(2))] = program
                found[program][0] += 1
        elif "sched_stat_runtime" in line:
            match = _RUNTIME.search(line)
            if match and int(match.group(1)) in name:
                found[name[int(match.group(1))]][1] += int(match.group(2)) / 1e9
    return dict(found)


def record(argv: list[str], runs: int, workdir: Path) -> tuple[list[str], float]:
    """Run ``argv`` ``runs`` times under `perf record -a`; the trace lines and the wall time."""
    data = workdir / "perf.data"
    script = workdir / "runs.sh"
    script.write_text(f"i=0; while [ $i -lt {runs} ]; do {shlex.join(argv)} >/dev/null 2>&1; i=$((i+1)); done\n")
    started = time.monotonic()
    subprocess.run(
        ["perf", "record", "-q", *sum((["-e", e] for e in EVENTS), []), "-a", "-o", str(data), "--", "sh", str(script)],
        check=True,
        capture_output=True,
    )
    wall = time.monotonic() - started
    out = subprocess.run(["perf", "script", "-i", str(data)], capture_output=True, text=True, check=True).stdout
    return out.splitlines(), wall


def measure(ssh: list[str], container: str, command: str, runs: int, workdir: Path) -> Cost:
    roots = container_tasks(container)
    load = os.getloadavg()[0]
    before = cgroup_cpu_ns(container)
    lines, wall = record([*ssh, command], runs, workdir)
    after = cgroup_cpu_ns(container)
    busy = attribute(lines, roots)
    idle_lines, _ = record(["sleep", f"{wall / runs:.3f}"], runs, workdir)
    idle = attribute(idle_lines, roots)
    programs = {}
    for program, (starts, seconds) in busy.items():
        # The robot's own background (its daemons, the payload's health
        # checks) over the same time is not the command's.
        idle_starts, idle_seconds = idle.get(program, [0, 0.0])
        programs[program] = (max(starts - idle_starts, 0) / runs, max(seconds - idle_seconds, 0.0) / runs)
    total = sum(seconds for _, seconds in programs.values())
    cgroup = (after - before) / runs / 1e9 if before is not None and after is not None else None
    return Cost(total, dict(sorted(programs.items(), key=lambda kv: -kv[1][1])), cgroup, load)


def merged(rounds: list[Cost]) -> Cost:
    """The mean of one command's rounds."""
    n = len(rounds)
    programs: dict[str, tuple[float, float]] = {}
    for cost in rounds:
        for program, (starts, seconds) in cost.programs.items():
            was = programs.get(program, (0.0, 0.0))
            programs[program] = (was[0] + starts / n, was[1] + seconds / n)
    cgroups = [c.cgroup for c in rounds if c.cgroup is not None]
    return Cost(
        sum(c.seconds for c in rounds) / n,
        dict(sorted(programs.items(), key=lambda kv: -kv[1][1])),
        sum(cgroups) / len(cgroups) if cgroups else None,
        sum(c.load for c in rounds) / n,
    )


def ratios(costs: dict[str, Cost]) -> str:
    """Each command's CPU against the first's (`sudo true`: what any SSH command costs)."""
    first, *others = costs
    return "; ".join(f"{n}: {costs[n].seconds / costs[first].seconds:.2f}x `{first}`" for n in others)


def table(costs: dict[str, Cost], top: int = 40) -> str:
    """Markdown: one column per command, one row per program (the dearest first)."""
    names = list(costs)
    programs: list[str] = []
    for cost in costs.values():
        programs += [p for p in cost.programs if p not in programs]
    programs.sort(key=lambda p: -max(c.programs.get(p, (0, 0.0))[1] for c in costs.values()))
    lines = ["| program | " + " | ".join(f"`{n}`: starts, CPU" for n in names) + " |", "|---|" + "---|" * len(names)]
    shown, rest = programs[:top], programs[top:]
    for program in shown:
        cells = []
        for n in names:
            starts, seconds = costs[n].programs.get(program, (0, 0.0))
            cells.append(f"{starts:g}, {seconds * 1000:.1f} ms" if starts or seconds >= 0.00005 else "–")
        lines.append(f"| {program} | " + " | ".join(cells) + " |")
    if rest:
        lines.append(
            "| (the others) | "
            + " | ".join(f"{sum(costs[n].programs.get(p, (0, 0.0))[1] for p in rest) * 1000:.1f} ms" for n in names)
            + " |"
        )
    lines.append("| **all, per run** | " + " | ".join(f"**{costs[n].seconds * 1000:.1f} ms**" for n in names) + " |")
    lines.append(
        "| the container's cgroup, per run (its background included) | "
        + " | ".join(f"{costs[n].cgroup * 1000:.1f} ms" if costs[n].cgroup is not None else "–" for n in names)
        + " |"
    )
    return "\n".join(lines)


def snapshot_command(prefix: str, host: str, workdir: Path) -> str:
    """The snapshot command a no-op deploy.py sends ``host`` (as pyinfra runs it: sudo sh -c)."""
    from tests.bench.profile import Lab, snapshot_script

    lab = Lab(prefix, 1, workdir)
    run = lab.run("deploy.py", "--limit", host)
    return f"sudo sh -c {shlex.quote(snapshot_script(run))}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m tests.bench.robot_cpu", description=__doc__.splitlines()[0])
    parser.add_argument("--prefix", default=os.environ.get("ROBOT_LAB_PREFIX", "perf"))
    parser.add_argument("--host", default="robot1")
    parser.add_argument("--runs", type=int, default=10, help="runs of each command a round")
    parser.add_argument("--rounds", type=int, default=4, help="rounds, the commands alternating")
    parser.add_argument("--snapshot", action="store_true", help="also the host's snapshot command")
    parser.add_argument("--write", action="store_true", help="write its section of tests/bench/PROFILE.md")
    parser.add_argument("commands", nargs="*", help="commands to run on the robot (default: sudo true)")
    args = parser.parse_args(argv)
    if not shutil.which("perf") or os.geteuid() != 0:
        print("robot_cpu: needs perf and root (perf record -a of the scheduler's tracepoints)", file=sys.stderr)
        return 1
    from tests.bench.fleet import Bench
    from tests.lab import state as lab_state

    with tempfile.TemporaryDirectory() as tmp:
        bench = Bench(args.prefix, 1, Path(tmp))
        bench.state = lab_state.load(args.prefix)
        container = next(h["container"] for h in bench.state["hosts"] if h["name"] == args.host)
        ssh = bench.ssh(args.host, "")[:-1]
        commands = {c: c for c in args.commands or ["sudo true"]}
        if args.snapshot:
            commands["the snapshot"] = snapshot_command(args.prefix, args.host, Path(tmp))
        # Rounds alternate the commands, so that a drift of the machine's
        # speed (other guests, frequency) falls on all of them alike.
        rounds: dict[str, list[Cost]] = {name: [] for name in commands}
        for _ in range(args.rounds):
            for name, command in commands.items():
                rounds[name].append(measure(ssh, container, command, args.runs, Path(tmp)))
        costs = {name: merged(r) for name, r in rounds.items()}
    print(table(costs))
    if len(costs) > 1:
        print("\n" + ratios(costs))
    loads = "1-minute load before each: " + ", ".join(f"{n} {c.load:.2f}" for n, c in costs.items())
    print("\n" + loads)
    if args.write:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
        sections.write(
            "robot_cpu",
            "\n".join(
                [
                    "## The robot's CPU per command, program by program",
                    "",
                    f"Written by `python3 -m tests.bench.robot_cpu --runs {args.runs} --rounds {args.rounds}"
                    f"{' --snapshot' if args.snapshot else ''} --write` "
                    f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, commit {commit.stdout.strip()}, "
                    f"{args.host} of a converged lab): every task descending from the robot container's processes, "
                    "from the kernel's scheduler tracepoints, per run, the robot's background over the same time "
                    "taken away; the container's cgroup count beside it.",
                    "",
                    table(costs),
                    "",
                    *([ratios(costs) + ".", ""] if len(costs) > 1 else []),
                    loads + ".",
                ]
            ),
            {"costs": {n: vars(c) for n, c in costs.items()}},
            HERE / "PROFILE.md",
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
