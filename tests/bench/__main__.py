"""One command for the fleet benchmark: figures for N = 3 and 10 simulated
robots, each next to a floor measured alternately on the same hosts.

    python3 -m tests.bench [--robots 3 10] [--runs 3] [--fresh-at 3] [--prefix bench] [--no-write] [--write-loaded]

Prints the figures and writes tests/bench/RESULTS.md and RESULTS.json.
Every figure is the median of --runs samples with its spread; before each
sample the benchmark waits for the 1-minute load average to fall below 1.5
(up to $ROBOT_BENCH_PATIENCE seconds, 600 by default) and records it.  If
any sample started above 1.5 the results are not written unless
--write-loaded is given, and then each such figure carries its load.
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

from tests.bench import hygiene, sections
from tests.bench.fleet import measure

HERE = Path(__file__).resolve().parent

# (ratio, N it is judged at, target, text)
TARGETS = [
    ("noop / pyinfra exec true", 10, 1.5, "no-op rerun at N=10 <= 1.5x `pyinfra exec -- true`"),
    ("noop / pyinfra exec true", 3, 1.5, "no-op rerun at N=3 <= 1.5x `pyinfra exec -- true`"),
    ("fresh / (apt+pull+health)", 3, 1.15, "fresh provision at N=3 <= 1.15x (apt floor + pull + health window)"),
    ("update all / update one", 10, 1.1, "update of all 10 <= 1.1x one robot"),
    ("max update window (s)", 10, 0.5, "update window <= 0.5 s on every robot (old FinishedAt -> new StartedAt)"),
    ("exits at once: exit -> old running (s)", 10, 1.0, "a release that exits at once: exit -> old running <= 1 s"),
    ("never healthy: unhealthy -> old running (s)", 10, 0.5, "what the tool adds after Docker's `unhealthy` <= 0.5 s"),
]

ROWS = [
    ("floor: N parallel `ssh true`", "floor_ssh_true"),
    ("floor: `pyinfra exec -- true`", "floor_exec_true"),
    ("no-op rerun", "noop"),
    ("floor: Docker's apt install + `docker pull`", "floor_apt_pull"),
    ("floor: payload health window (run -> healthy)", "floor_health"),
    ("floor: apt + pull + health window", "floor_fresh"),
    ("fresh provision", "fresh"),
    ("update all N", "update_all"),
    ("update one", "update_one"),
    ("rollout of the whole fleet (canary 1, batch 50%)", "rollout"),
    ("update window, all N at once: every robot's (old FinishedAt -> new StartedAt)", "window_all"),
    ("update window, one robot", "window_one"),
    ("broken release, exits at once: deploy until failed", "broken_exit_deploy"),
    ("exits at once: its exit (Docker's verdict) -> old release running", "broken_exit_verdict"),
    ("exits at once: its first start -> old release running", "broken_exit_first"),
    ("broken release, runs but never healthy: deploy until failed", "broken_unhealthy_deploy"),
    ("never healthy: Docker's `unhealthy` -> old release running", "broken_unhealthy_verdict"),
    ("never healthy: its first start -> old release running", "broken_unhealthy_first"),
]


def fmt(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.2f}"
    return str(value)


def all_idle(results: list[dict]) -> bool:
    return all(f.get("idle") for r in results for f in r["figures"].values())


def markdown(results: list[dict], conditions: dict) -> str:
    ns = [r["robots"] for r in results]
    lines = [
        "# Fleet benchmark results",
        "",
        "Written by `python3 -m tests.bench`; seconds unless said otherwise.  Each figure: median of "
        f"{results[0]['runs']} samples (min–max); a figure with a sample that did not start idle (its first "
        "at a 1-minute load average of 1.5 or more, a later one with 0.5 cores or more busy) carries "
        "`[load X]`, the highest load before its samples.",
        "",
        "## Conditions",
        "",
    ]
    lines += [f"- {k}: {v}" for k, v in conditions.items()]
    if not all_idle(results):
        lines += [
            "",
            "**Not every figure was taken on an idle machine** (see `[load X]`): "
            "such figures and their ratios are development figures, not results.",
        ]
    lines += ["", "## Figures", "", "| figure | " + " | ".join(f"N={n}" for n in ns) + " |", "|---|" + "---|" * len(ns)]
    for title, key in ROWS:
        lines.append(f"| {title} | " + " | ".join(hygiene.shown(r["figures"].get(key)) for r in results) + " |")
    lines.append(
        "| no-op: SSH commands per host | " + " | ".join(fmt(r.get("noop_commands_per_host")) for r in results) + " |"
    )
    lines.append(
        "| fresh: SSH commands per host | "
        + " | ".join(
            fmt(max(r["fresh_commands_per_host"])) if r.get("fresh_commands_per_host") else "-" for r in results
        )
        + " |"
    )
    lines.append("| rollout: waves | " + " | ".join(fmt(r.get("rollout_waves")) for r in results) + " |")
    lines.append(
        "| update window per robot, all N at once: median (min–max) over the runs | "
        + " | ".join(per_robot(r.get("window", {})) for r in results)
        + " |"
    )
    lines.append(
        "| load average at start / end (1 min) | "
        + " | ".join(f"{r['load_at_start'][0]:.2f} / {r['load_at_end'][0]:.2f}" for r in results)
        + " |"
    )
    settings = [(kind, text) for r in results for kind, text in (r.get("broken_settings") or {}).items()]
    if settings:
        lines += ["", "Broken releases (robot1), with the health-check settings they ran with:", ""]
        lines += [f"- {kind}: {text}" for kind, text in settings]
    lines += [
        "",
        "## Ratios to the floors (medians)",
        "",
        "| ratio | " + " | ".join(f"N={n}" for n in ns) + " | target |",
        "|---|" + "---|" * (len(ns) + 1),
    ]
    for key in results[0]["ratios"]:
        cells = []
        for r in results:
            value = r["ratios"].get(key)
            mark = "" if value is None or r.get("ratios_idle", {}).get(key, True) else " [loaded]"
            cells.append(fmt(value) + mark)
        targets = "; ".join(
            f"{text}: **{verdict(results, key, n, limit)}**" for k, n, limit, text in TARGETS if k == key
        )
        lines.append(f"| {key} | " + " | ".join(cells) + f" | {targets} |")
    return "\n".join(lines) + "\n"


def per_robot(windows: dict) -> str:
    """robot: median (min–max) of its update windows, for each robot."""
    if not windows:
        return "-"
    parts = []
    for host, values in windows.items():
        figure = hygiene.Figure(list(values), [0.0] * len(values)).as_dict()
        shown = f"{figure['median']:.2f}" + (f" ({figure['min']:.2f}–{figure['max']:.2f})" if len(values) > 1 else "")
        parts.append(f"{host} {shown}")
    return ", ".join(parts)


def verdict(results: list[dict], key: str, n: int, limit: float) -> str:
    found = next((r for r in results if r["robots"] == n), None)
    if found is None or found["ratios"].get(key) is None:
        return f"not measured at N={n}"
    met = "met" if found["ratios"][key] <= limit else "missed"
    return met if found.get("ratios_idle", {}).get(key, False) else f"{met}, loaded"


EPILOG = """\
The update window of each of 10 robots updated at once (issue 29), on an
idle machine, written to RESULTS.md:
    python3 -m tests.bench --robots 10 --updates-at 10 --fresh-at --runs 3
only printed (a check that it runs: a small lab, no wait for an idle machine):
    ROBOT_BENCH_PATIENCE=0 python3 -m tests.bench --robots 2 --updates-at 2 --fresh-at --runs 1 --no-write
Each robot's window is the row "update window per robot, all N at once"
(median and spread over the runs), all of them together the row "update
window, all N at once"; one robot alone: python3 -m tests.bench.releases."""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python3 -m tests.bench",
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=EPILOG,
    )
    parser.add_argument("--robots", type=int, nargs="+", default=[3, 10])
    parser.add_argument("--runs", type=int, default=3, help=f"samples per figure (at least {hygiene.MIN_SAMPLES})")
    parser.add_argument("--fresh-at", type=int, nargs="*", default=[3], help="N at which to time fresh provisions")
    parser.add_argument(
        "--updates-at", type=int, nargs="*", default=[10], help="N at which to time updates, rollouts, crashes"
    )
    parser.add_argument("--prefix", default=os.environ.get("ROBOT_LAB_PREFIX", "bench"))
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--write-loaded", action="store_true", help="write even figures taken under load (marked)")
    parser.add_argument("--keep", action="store_true", help="leave the last lab up")
    args = parser.parse_args(argv)
    if args.runs < hygiene.MIN_SAMPLES and not args.no_write:
        parser.error(
            f"--runs {args.runs}: results need at least {hygiene.MIN_SAMPLES} samples a figure (or --no-write)"
        )
    results = []
    for n in args.robots:
        result = measure(
            n, args.prefix, keep=args.keep, runs=args.runs, fresh=n in args.fresh_at, updates=n in args.updates_at
        )
        results.append(result)
        print(json.dumps(result, indent=2), flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    conditions = {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "commit": commit,
        "cpus": os.cpu_count(),
        "load limit before each figure's first sample (1 min)": hygiene.LIMIT,
        "before its later samples": f"fewer than {hygiene.QUIET} cores busy over {hygiene.QUIET_WINDOW:.0f} s",
    }
    text = markdown(results, conditions)
    print(text)
    if args.no_write:
        return 0
    if not all_idle(results) and not args.write_loaded:
        print(
            "[bench] not written: some samples started at a load average >= "
            f"{hygiene.LIMIT} (see [load X] above); rerun on an idle machine, or pass --write-loaded",
            file=sys.stderr,
        )
        return 1
    (HERE / "RESULTS.json").write_text(json.dumps({"conditions": conditions, "results": results}, indent=2) + "\n")
    (HERE / "RESULTS.md").write_text(sections.rewrite_main(text))  # the other benchmarks' sections kept
    return 0


if __name__ == "__main__":
    sys.exit(main())
