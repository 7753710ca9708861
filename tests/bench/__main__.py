"""One command for the fleet benchmark: figures for N = 1, 3 (and 10)
simulated robots, each next to a floor measured in the same run.

    python3 -m tests.bench [--robots 1 3 10] [--prefix bench] [--no-write]

Prints the figures and writes tests/bench/RESULTS.md and RESULTS.json.
Nothing here is a test: targets are compared, never asserted.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
from pathlib import Path

from tests.bench.fleet import measure

HERE = Path(__file__).resolve().parent

TARGETS = [
    ("noop / pyinfra exec true", 1.5, "no-op rerun at N=10 <= 1.5x `pyinfra exec -- true`"),
    ("fresh / (apt+pull+health)", 1.15, "fresh provision at N=3 <= 1.15x (apt floor + pull + health window)"),
    ("update all / update one", 1.1, "update of all N <= 1.1x one robot"),
    ("max downtime (s)", 1.0, "payload downtime <= 1 s per robot"),
]

ROWS = [
    ("floor: N parallel `ssh true`", "floor_ssh_true"),
    ("floor: `pyinfra exec -- true`", "floor_exec_true"),
    ("floor: Docker's apt install + `docker pull`", "floor_apt_pull"),
    ("floor: payload health window (run -> healthy)", "floor_health"),
    ("fresh provision", "fresh"),
    ("no-op rerun (median)", "noop"),
    ("no-op: SSH commands per host", "noop_commands_per_host"),
    ("rollout of the whole fleet (canary 1, batch 50%)", "rollout"),
    ("rollout: waves", "rollout_waves"),
    ("update all N", "update_all"),
    ("update one", "update_one"),
    ("crash-looping release: deploy until failed", "crash_deploy"),
    ("crash-looping start -> old release started", "crash_to_old_running"),
]


def fmt(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.2f}"
    return str(value)


def markdown(results: list[dict], conditions: dict) -> str:
    ns = [r["robots"] for r in results]
    lines = ["# Fleet benchmark results", "",
             "Written by `python3 -m tests.bench`; seconds unless said otherwise.", "",
             "## Conditions", ""]
    lines += [f"- {k}: {v}" for k, v in conditions.items()]
    lines += ["", "## Figures", "", "| figure | " + " | ".join(f"N={n}" for n in ns) + " |",
              "|---|" + "---|" * len(ns)]
    for title, key in ROWS:
        lines.append(f"| {title} | " + " | ".join(fmt(r.get(key)) for r in results) + " |")
    lines.append("| payload downtime per robot | " + " | ".join(
        ", ".join(fmt(v) for v in r["downtime"].values()) for r in results) + " |")
    lines.append("| load average at start (1/5/15 min) | " + " | ".join(
        "/".join(fmt(x) for x in r["load_at_start"]) for r in results) + " |")
    lines += ["", "## Ratios to the floors", "", "| ratio | " + " | ".join(f"N={n}" for n in ns) + " | target |",
              "|---|" + "---|" * (len(ns) + 1)]
    targets = {key: text for key, _, text in TARGETS}
    for key in results[0]["ratios"]:
        lines.append(f"| {key} | " + " | ".join(fmt(r["ratios"].get(key)) for r in results)
                     + f" | {targets.get(key, '')} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m tests.bench", description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, nargs="+", default=[1, 3, 10])
    parser.add_argument("--prefix", default=os.environ.get("ROBOT_LAB_PREFIX", "bench"))
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--keep", action="store_true", help="leave the last lab up")
    args = parser.parse_args(argv)
    results = []
    for n in args.robots:
        result = measure(n, args.prefix, keep=args.keep)
        results.append(result)
        print(json.dumps(result, indent=2), flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    conditions = {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "commit": commit,
        "cpus": os.cpu_count(),
        "load average at the end (1/5/15 min)": "/".join(f"{x:.1f}" for x in os.getloadavg()),
    }
    text = markdown(results, conditions)
    print(text)
    if not args.no_write:
        (HERE / "RESULTS.json").write_text(json.dumps({"conditions": conditions, "results": results}, indent=2) + "\n")
        (HERE / "RESULTS.md").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
