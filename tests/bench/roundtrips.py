"""Benchmark: SSH commands and file transfers per host, and wall time, for a
run of deploy.py against the simulated fleet.  Prints figures; asserts
nothing (targets live here, not in timed tests).

    python3 -m tests.bench.roundtrips [--prefix lab] [--runs 2]

A converged rerun should cost one command per host (the host snapshot) on
top of connecting.  Each SSH command is an exec channel: about two round
trips (open + exec, then output and close); connecting is about five
(TCP, key exchange, auth).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

from tests.fixtures import ROOT, pyinfra_argv

# Runs inside the pyinfra process before its CLI (the report's path its first
# argument): wrap the SSH connector and count.
COUNTING = r"""
import atexit, collections, json, sys
from pyinfra.connectors.ssh import SSHConnector
REPORT = sys.argv.pop(1)
counts = collections.defaultdict(lambda: collections.Counter())
def wrap(name, kind):
    original = getattr(SSHConnector, name)
    def counted(self, *args, **kwargs):
        counts[self.host.name][kind] += 1
        return original(self, *args, **kwargs)
    setattr(SSHConnector, name, counted)
wrap("connect", "connects")
wrap("run_shell_command", "commands")
wrap("_put_file", "uploads")
wrap("_get_file", "downloads")
@atexit.register
def report():
    with open(REPORT, "w") as out:
        json.dump(counts, out)
"""


def run_once(prefix: str, label: str) -> dict:
    out = ROOT / ".lab" / prefix / "roundtrips.json"
    env = dict(os.environ, ROBOT_LAB_PREFIX=prefix, PYINFRA_PROGRESS="off")
    started = time.monotonic()
    proc = subprocess.run(
        pyinfra_argv(str(out), "-y", "inventories/lab.py", "deploy.py", setup=COUNTING),
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    seconds = time.monotonic() - started
    counts = json.loads(out.read_text())
    print(f"\n{label}: exit {proc.returncode}, {seconds:.1f} s wall for {len(counts)} hosts")
    print(f"  {'host':10} {'connects':>8} {'commands':>8} {'uploads':>8}")
    for host, c in sorted(counts.items()):
        print(f"  {host:10} {c.get('connects', 0):>8} {c.get('commands', 0):>8} {c.get('uploads', 0):>8}")
    return {"seconds": seconds, "counts": counts, "exit": proc.returncode}


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--prefix", default="bench")
    parser.add_argument("--runs", type=int, default=2, help="runs after the first (converged reruns)")
    parser.add_argument("--keep", action="store_true", help="leave the lab up")
    args = parser.parse_args()
    from tests.lab import hosts

    fresh = not (ROOT / ".lab" / args.prefix / "state.json").exists()
    hosts.up(args.prefix)
    results = [run_once(args.prefix, "first run" + (" (fresh hosts)" if fresh else ""))]
    for index in range(args.runs):
        results.append(run_once(args.prefix, f"converged rerun {index + 1}"))
    rerun = results[-1]
    per_host = [c.get("commands", 0) for c in rerun["counts"].values()]
    print(f"\nconverged rerun: {max(per_host)} command(s) per host at most, {rerun['seconds']:.1f} s wall")
    if not args.keep:
        hosts.down(args.prefix)
    return 0


if __name__ == "__main__":
    sys.exit(main())
