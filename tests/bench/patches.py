"""What each of robotfleet/pyinfra_patches.py's replacements saves the operator.

    python3 -m tests.bench.patches [--hosts 250] [--runs 5] [--keys order connectors ...]

A no-op of ``--hosts`` converged robots planned and run through pyinfra's
own API as `pyinfra -y` runs them, against @fake hosts (tests/unit/harness.py:
every host answers the snapshot as a converged robot; no SSH, so what is
left is the operator's planning, where these replacements act), in a fresh
process each time: with
every replacement in place, and with each one left out in turn (pyinfra's
own function runs there), the variants taking turns.  Prints the median CPU
seconds of each and what the one left out costs per host.  Asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# One process: leave out the replacements named in argv[1] (JSON), then time the plan.
RUN = r"""
import json, sys, time
from robotfleet import pyinfra_patches
left_out, changed = json.loads(sys.argv[1]), pyinfra_patches._changed
pyinfra_patches._changed = lambda key: "left:out" if key in left_out else changed(key)  # as if pyinfra changed it
from pyinfra.api import State
State.should_check_for_changes = lambda self: False  # as `pyinfra -y` runs (the CLI's check_for_changes)
from tests.unit.harness import ROBOT, converged, plan
snap = converged("robots", ROBOT, "ubuntu-24.04")
hosts = {f"r{i}": ("robots", ROBOT, snap) for i in range(int(sys.argv[2]))}
started = time.process_time()
result = plan(hosts)
cpu = time.process_time() - started
assert not result.failed and not any(result[name] for name in hosts), "not a no-op"
print(json.dumps({"cpu": cpu, "installed": pyinfra_patches.install()}))
"""


def one(left_out: list[str], hosts: int) -> dict:
    done = subprocess.run(
        [sys.executable, "-c", RUN, json.dumps(left_out), str(hosts)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(done.stdout.splitlines()[-1])


def main(argv=None) -> int:
    from robotfleet import pyinfra_patches

    parser = argparse.ArgumentParser(prog="python3 -m tests.bench.patches", description=__doc__.splitlines()[0])
    parser.add_argument("--hosts", type=int, default=250)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--keys", nargs="*", default=list(pyinfra_patches.SPEEDUPS), help="the ones to leave out")
    args = parser.parse_args(argv)
    variants = {"all in place": [], **{f"without {key}": [key] for key in args.keys}}
    found: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(args.runs):  # the variants take turns: a drift of the machine falls on all alike
        for name, left_out in variants.items():
            found[name].append(one(left_out, args.hosts)["cpu"])
    base = statistics.median(found["all in place"])
    print(f"a no-op of {args.hosts} @fake converged robots, CPU seconds, median of {args.runs} (min-max):")
    for name, cpus in found.items():
        cost = statistics.median(cpus) - base
        per_host = cost / args.hosts * 1000
        extra = "" if name == "all in place" else f"; left out: {cost:+.2f} s, {per_host:+.2f} ms a host"
        print(f"- {name}: {statistics.median(cpus):.2f} s ({min(cpus):.2f}-{max(cpus):.2f}){extra}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
