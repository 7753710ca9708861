"""Where a converged rerun spends its time beyond `pyinfra exec -- true`.

    python3 -m tests.bench.profile [--prefix perf] [--robots 10] [--runs 3] [--write]

On a running, converged lab (python3 -m tests.lab up, then one deploy), runs
`pyinfra exec -- true` and the no-op `deploy.py` alternately, each inside a
wrapper that records, in the pyinfra process itself:

- the wall and CPU time of each of pyinfra's stages (start-up and
  inventory, connect, prepare, execute, results), from ``State.set_stage``;
- every SSH command's wall time, per host;
- a sampling profile: a real OS thread (not a gevent greenlet) looks at the
  main thread's stack every 5 ms; greenlets all run on that thread, so a
  sample is whatever Python code runs, and the gevent hub waiting on sockets
  counts as idle.

and, on the first robot over plain SSH, the snapshot script alone against
`true`.  Prints a summary; --write puts it in tests/bench/PROFILE.md.
Nothing here is a test: it asserts nothing.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tests.bench import hygiene, sections

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent

# Runs as `python -c WRAPPER REPORT pyinfra-args...`.
WRAPPER = r"""
import _thread, atexit, collections, json, sys, time
REPORT = sys.argv.pop(1)
_sleep, _perf, _cpu = time.sleep, time.perf_counter, time.process_time
marks = [("start", _perf(), _cpu())]
samples = collections.Counter()
main_id = _thread.get_ident()
running = [True]

def sampler():
    while running[0]:
        frame = sys._current_frames().get(main_id)
        stack = []
        while frame is not None:
            code = frame.f_code
            stack.append(f"{code.co_name} ({code.co_filename.rsplit('/', 2)[-2:][-1]}:{code.co_firstlineno})"
                         f"|{code.co_filename}")
            frame = frame.f_back
        samples[";".join(reversed(stack))] += 1
        _sleep(0.005)

_thread.start_new_thread(sampler, ())

from pyinfra.api.state import State
_set_stage = State.set_stage
def set_stage(self, stage):
    marks.append((stage.name, _perf(), _cpu()))
    return _set_stage(self, stage)
State.set_stage = set_stage

from pyinfra.connectors.ssh import SSHConnector
commands, texts = [], {}
_run = SSHConnector.run_shell_command
def run_shell_command(self, command, *args, **kwargs):
    started = _perf()
    texts.setdefault(self.host.name, str(command))
    try:
        return _run(self, command, *args, **kwargs)
    finally:
        op = getattr(self.host, "current_op_hash", None)
        meta = self.state.op_meta.get(op) if op else None
        name = ", ".join(sorted(meta.names)) if meta else "(the snapshot)"
        commands.append((self.host.name, _perf() - started, started - marks[0][1], name))
SSHConnector.run_shell_command = run_shell_command

@atexit.register
def report():
    running[0] = False
    marks.append(("end", _perf(), _cpu()))
    with open(REPORT, "w") as out:
        json.dump({"marks": marks, "commands": commands, "texts": texts, "samples": dict(samples)}, out)

from pyinfra_cli.main import main
sys.argv[0] = "pyinfra"
main()
"""

# (category, substrings of a sampled stack: the first category matching wins)
CATEGORIES = [
    ("idle: waiting for the hosts (gevent hub)", ["run (hub.py"]),
    ("imports (Python modules)", ["_find_and_load"]),
    ("inventory: fleet file load + check", ["/inventories/", "/robotfleet/inventory.py"]),
    ("pyinfra: operation order from the stack", ["get_operation_order_from_stack", "operation_order_from_stack"]),
    ("pyinfra: global arguments of operations", ["pop_global_arguments"]),
    ("host data check (per host)", ["data_problems"]),
    ("snapshot: script + parse", ["/robotfleet/host/snapshot.py"]),
    ("roles' steps: building operations", ["/roles/", "/robotfleet/host/"]),
    ("pyinfra: other operation bookkeeping", ["/pyinfra/api/operation.py"]),
    ("SSH: paramiko (keys, ciphers, channels)", ["/paramiko/"]),
    ("pyinfra: execute + results", ["run_ops", "print_results", "/pyinfra/api/operations.py"]),
    ("pyinfra CLI and the rest", [""]),
]


def categorize(samples: dict) -> dict[str, int]:
    found: collections.Counter = collections.Counter()
    for stack, count in samples.items():
        innermost = stack.rsplit(";", 1)[-1]
        if innermost.startswith("run (hub.py") or not stack:
            found[CATEGORIES[0][0]] += count
            continue
        for name, keys in CATEGORIES[1:]:
            if any(key in stack for key in keys):
                found[name] += count
                break
    return dict(found)


class Lab:
    def __init__(self, prefix: str, robots: int, workdir: Path):
        from tests.bench.fleet import Bench

        self.bench = Bench(prefix, robots, workdir)
        from tests.lab import state as lab_state

        self.bench.state = lab_state.load(prefix)
        self.bench.robots = [h["name"] for h in self.bench.state["hosts"]][:robots]
        self.workdir = workdir

    def run(self, *args: str) -> dict:
        report = self.workdir / "profile.json"
        started = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, "-c", WRAPPER, str(report), "-y", "inventories/lab.py", *args],
            cwd=ROOT,
            env=self.bench.env(),
            capture_output=True,
            text=True,
        )
        wall = time.perf_counter() - started
        if proc.returncode != 0:
            raise RuntimeError(f"pyinfra {' '.join(args)}: exit {proc.returncode}: {proc.stderr[-600:]}")
        data = json.loads(report.read_text())
        data["wall"] = wall
        return data

    def on_robot(self, script: str, runs: int) -> list[float]:
        """Seconds ``script`` takes on the first robot (sudo sh), timed there."""
        timed = 's=$(date +%s%N); sudo sh -c "$1" >/dev/null 2>&1; e=$(date +%s%N); echo $(( (e - s) / 1000 ))'
        command = f"sh -c {_q(timed)} timed {_q(script)}"
        return [
            int(
                subprocess.run(
                    self.bench.ssh(self.bench.robots[0], command), capture_output=True, text=True, check=True
                ).stdout.strip()
            )
            / 1e6
            for _ in range(runs)
        ]


def cgroup_cpu_ns(container: str) -> int | None:
    """CPU the container's cgroup has used, in ns (cgroup v1 cpuacct or v2 cpu.stat)."""
    cid = subprocess.run(
        ["docker", "inspect", "-f", "{{.Id}}", container], capture_output=True, text=True
    ).stdout.strip()
    v1 = Path(f"/sys/fs/cgroup/cpuacct/docker/{cid}/cpuacct.usage")
    if v1.exists():
        return int(v1.read_text())
    v2 = Path(f"/sys/fs/cgroup/system.slice/docker-{cid}.scope/cpu.stat")
    if v2.exists():
        usage = next(line for line in v2.read_text().splitlines() if line.startswith("usage_usec"))
        return int(usage.split()[1]) * 1000
    return None


def robot_cpu(lab: "Lab", command: str, runs: int = 5) -> float | None:
    """CPU seconds the first robot's container spends per SSH ``command``
    (sshd, sudo, the command and the daemons it asks), its idle background
    included: compare with `true`."""
    container = lab.bench.state["hosts"][0]["container"]
    before = cgroup_cpu_ns(container)
    if before is None:
        return None
    for _ in range(runs):
        subprocess.run(lab.bench.ssh(lab.bench.robots[0], command), capture_output=True)
    return (cgroup_cpu_ns(container) - before) / runs / 1e9


def _q(text: str) -> str:
    import shlex

    return shlex.quote(text)


def stages(data: dict) -> dict[str, tuple[float, float]]:
    """stage -> (wall, cpu) seconds, the start-up (imports, inventory) first."""
    names = {
        "start": "start-up, inventory",
        "Connect": "connect",
        "Prepare": "prepare",
        "Execute": "execute",
        "Disconnect": "results, exit",
    }
    marks = data["marks"]
    return {names.get(a[0], a[0]): (b[1] - a[1], b[2] - a[2]) for a, b in zip(marks, marks[1:])}


def snapshot_script(run: dict) -> str:
    """The first command a no-op run sent to a host: the snapshot script."""
    return next(iter(run["texts"].values()))


def fresh_timeline(prefix: str, workdir: Path) -> str:
    """A fresh provision of one robot, command by command, beside the floor
    (Docker's apt install + pull, then the health window) on the same reset
    host: what the provision does beyond the floor."""
    from tests.bench.fleet import Bench

    bench = Bench(prefix, 1, workdir)
    bench.up(fresh=True)
    bench.parallel_ssh(bench.apt_floor_script())  # warm the apt cache and the registry
    bench.up(fresh=True)
    load = hygiene.wait_for_idle("fresh timeline: floor")
    floor = bench.parallel_ssh(bench.apt_floor_script())
    health = bench.health_window()
    bench.up(fresh=True)
    load_fresh = hygiene.wait_for_idle("fresh timeline: provision")
    lab = Lab.__new__(Lab)
    lab.bench, lab.workdir = bench, workdir
    run = lab.run("deploy.py")
    bench.down()
    lines = [
        "## A fresh provision of one robot, command by command",
        "",
        f"Floor on the same reset host: apt + pull {floor:.2f} s, health window {health:.2f} s, "
        f"together {floor + health:.2f} s (load before: {load:.2f}).  The provision: {run['wall']:.2f} s "
        f"(load before: {load_fresh:.2f}), {run['wall'] / (floor + health):.2f}x.",
        "",
        "| starts at (s) | takes (s) | operation |",
        "|---|---|---|",
    ]
    stage = {name: round(wall, 2) for name, (wall, _) in stages(run).items()}
    lines.insert(4, "Stages: " + ", ".join(f"{k} {v} s" for k, v in stage.items()) + ".")
    lines.insert(5, "")
    for _, seconds, start, name in run["commands"]:
        lines.append(f"| {start:.2f} | {seconds:.2f} | {name} |")
    return "\n".join(lines) + "\n"


def median_spread(values: list[float]) -> str:
    return f"{statistics.median(values):.2f} ({min(values):.2f}–{max(values):.2f})"


def summarize(runs: dict[str, list[dict]], robot: dict[str, list[float]], robots: int, loads: list[float]) -> str:
    lines = [
        f"# Profile: a converged rerun of {robots} robots against `pyinfra exec -- true`",
        "",
        "Written by `python3 -m tests.bench.profile --write`; medians of "
        f"{len(runs['noop'])} alternating runs (min–max), seconds.  Load average (1 min) before each run: "
        + ", ".join(f"{x:.2f}" for x in loads)
        + " (the first runs waited for a load below 1.5, the later "
        "ones for a quiet machine: tests/bench/hygiene.py).",
        "",
    ]
    lines += [
        "## Wall and CPU by pyinfra stage",
        "",
        "| stage | exec true: wall | exec true: CPU | no-op: wall | no-op: CPU |",
        "|---|---|---|---|---|",
    ]
    names = list(stages(runs["noop"][0]))
    for name in names:
        cells = []
        for kind in ("exec", "noop"):
            cells.append(median_spread([stages(r)[name][0] for r in runs[kind]]))
            cells.append(median_spread([stages(r)[name][1] for r in runs[kind]]))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    total = {kind: [r["wall"] for r in runs[kind]] for kind in runs}
    cpu = {kind: [r["marks"][-1][2] - r["marks"][0][2] for r in runs[kind]] for kind in runs}
    lines.append(
        f"| **whole run** (wall from outside) | {median_spread(total['exec'])} | {median_spread(cpu['exec'])} "
        f"| {median_spread(total['noop'])} | {median_spread(cpu['noop'])} |"
    )
    lines += ["", "## SSH commands", ""]
    for kind in ("exec", "noop"):
        per_run = [[c[1] for c in r["commands"]] for r in runs[kind]]
        lines.append(
            f"- {kind}: {len(per_run[0])} commands per run ({len(per_run[0]) // robots} per host); "
            f"each {median_spread([statistics.median(p) for p in per_run])} s median, "
            f"slowest {median_spread([max(p) for p in per_run])} s"
        )
    lines += [
        "",
        "## The robot's side (first robot, alone, over SSH, timed on the robot)",
        "",
        f"- `true`: {median_spread(robot['true'])} s",
        f"- the snapshot script: {median_spread(robot['snapshot'])} s",
    ]
    if robot.get("cpu_snapshot") is not None:
        lines += [
            f"- CPU the robot's container spends per SSH command, as its cgroup counts it (sshd, sudo, the "
            f"command, the daemons it asks, and the container's own background over the same time): "
            f"`sudo true` {robot['cpu_true']:.3f} s, the snapshot {robot['cpu_snapshot']:.3f} s; "
            f"{robots} robots on this machine's {os.cpu_count()} cores: at least "
            f"{robots * (robot['cpu_snapshot'] - robot['cpu_true']) / os.cpu_count():.2f} s of wall for the "
            "snapshots beyond `true`, were the cores idle"
        ]
    lines += [""]
    lines += [
        "## Where the operator's CPU goes (sampled every 5 ms, all runs added)",
        "",
        "| category | exec true | no-op |",
        "|---|---|---|",
    ]
    cats = {kind: collections.Counter() for kind in runs}
    for kind in runs:
        for r in runs[kind]:
            cats[kind].update(categorize(r["samples"]))
    n = {kind: len(runs[kind]) for kind in runs}
    for name, _ in CATEGORIES:
        if cats["exec"][name] or cats["noop"][name]:
            lines.append(
                f"| {name} | {cats['exec'][name] * 0.005 / n['exec']:.2f} s | "
                f"{cats['noop'][name] * 0.005 / n['noop']:.2f} s |"
            )
    lines.append("")
    lines.append("(Samples are taken every 5 ms of wall time while Python runs; per run, averaged.)")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m tests.bench.profile", description=__doc__.splitlines()[0])
    parser.add_argument("--prefix", default=os.environ.get("ROBOT_LAB_PREFIX", "perf"))
    parser.add_argument("--robots", type=int, default=10)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument(
        "--fresh",
        metavar="PREFIX",
        help="also time a fresh provision of one robot, command by "
        "command, on a lab PREFIX of its own (reset, then removed)",
    )
    parser.add_argument("--write", action="store_true", help="write tests/bench/PROFILE.md")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        lab = Lab(args.prefix, args.robots, Path(tmp))
        lab.run("exec", "--", "true")  # warm the page cache and the hosts' sshd
        runs: dict[str, list[dict]] = {"exec": [], "noop": []}
        loads = []
        for index in range(args.runs):
            for kind, command in (("exec", ("exec", "--", "true")), ("noop", ("deploy.py",))):
                loads.append(hygiene.wait(kind, first=index == 0)[0])
                runs[kind].append(lab.run(*command))
        script = snapshot_script(runs["noop"][0])
        robot = {
            "true": lab.on_robot("true", 5),
            "snapshot": lab.on_robot(script, 5),
            "cpu_true": robot_cpu(lab, "sudo true"),
            "cpu_snapshot": robot_cpu(lab, f"sudo sh -c {_q(script)}"),
        }
    text = summarize(runs, robot, args.robots, loads)
    if args.fresh:
        with tempfile.TemporaryDirectory() as tmp:
            text += "\n" + fresh_timeline(args.fresh, Path(tmp))
    print(text)
    if args.write:
        (HERE / "PROFILE.md").write_text(sections.rewrite_main(text, HERE / "PROFILE.md"))  # robot_cpu's kept
    return 0


if __name__ == "__main__":
    sys.exit(main())
