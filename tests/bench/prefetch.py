"""Benchmark: a maintenance window opens -> the payload healthy on the new
release, with the release prefetched before the window (issue 35 item 6)
and with nothing prefetched.  Prints figures; asserts nothing; not part of
the test command (it builds its own lab).

    python3 -m tests.bench.prefetch [--prefix pf] [--robots 3] [--runs 3] [--keep] [--no-write]

Each run, on every robot of the lab (pull agents installed as
tests/bench/pull.py's setup does):

1. a release whose fleet file gives the robots a maintenance window opening
   a few minutes ahead (``daily HH:MM-HH:MM UTC``; applied while the last
   run's window, or none, is open), so the next release waits for it;
2. the new release's payload image removed from each robot, so its pull
   really goes to the registry; the robots' timers run as in the field, at
   an interval of an hour (``TIMER``), so only the benchmark wakes them
   (a stopped timer is a change the release's plan would put right: no
   switch could be prepared);
3. a release of the other payload tag published; with prefetch, each robot
   woken once now: it reports ``prefetched`` (code, wheels, images by
   digest in place); without, no robot checks before the window: its first
   check of the release is the one in the window, as before prefetch;
4. at the window's first second every robot is woken; measured per robot:
   its applying wake's own seconds (its journal line: fetch, verify,
   download, converge, the payload's health gate), the part of them up to
   the end of its prepared switch (the payload healthy on the new release:
   ``switched``, the line's seconds less its phases after the switch) and,
   from the moment of the wake, the time until its report says the release
   applied and the payload healthy.

The two modes alternate run by run, on the same lab and images.  Figures
wait for an idle machine before each window (tests/bench/hygiene.py); when
every window started idle they are written to RESULTS.md's section
``prefetch`` (tests/bench/sections.py), with each phase of the applying
wake (its journal line: robotfleet/pull/robot/journal.py).
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

from tests.bench import hygiene, sections
from tests.bench.pull import journal, phases, run_conditions, setup
from tests.bench.sections import cell

LEAD = 240  # seconds from a run's start to its window: the settings release applied, the prefetch done
TIMER = {"pull_interval": 3600, "pull_jitter": 0}  # the timers never wake a robot within a run


def window_ahead(now: datetime.datetime, lead: int = LEAD, span_minutes: int = 30) -> tuple[datetime.datetime, str]:
    """The first whole minute at least ``lead`` seconds after ``now``, and a
    daily UTC window opening then (pure)."""
    opens = (now + datetime.timedelta(seconds=lead + 59)).replace(second=0, microsecond=0)
    ends = opens + datetime.timedelta(minutes=span_minutes)
    return opens, f"daily {opens:%H:%M}-{ends:%H:%M} UTC"


def window_run(lab, op, tag: str, prefetch: bool) -> dict:
    """One run (the module's steps): its figures."""
    from tests.lab import pullfleet

    opens, window = window_ahead(datetime.datetime.now(datetime.timezone.utc))
    other = "1.0" if tag == "1.1" else "1.1"
    op.publish(
        pullfleet.fleet_text(op.lab, payload_tag=other, pull_windows=[window], **TIMER),
        f"window {window}",
        "--pause",
        "0",
        "--no-wheels",
        "--canary",
        "100%",
    )
    lab.trigger(lab.robots)  # applied inside the previous window (or none): the new window in agent.json
    image = f"{op.lab['registry']}/ros/payload@{pullfleet.digest_of(op.lab, 'ros/payload', tag)}"
    for robot in lab.robots:
        lab.sh(robot, f"docker image rm -f {image} >/dev/null 2>&1; true")  # not running: the other tag runs
    done = op.publish(
        pullfleet.fleet_text(op.lab, payload_tag=tag, pull_windows=[window], **TIMER),
        f"bench {tag}",
        "--pause",
        "0",
        "--no-wheels",
        "--canary",
        "100%",
    )
    version = int(re.search(r"release (\d+)", done.stdout).group(1))
    if prefetch:
        lab.trigger(lab.robots)
    said = {robot: (journal(lab, robot) or [{}])[-1].get("result") for robot in lab.robots}
    load, idle = hygiene.wait(
        f"window {window}",
        first=True,
        patience=max(1, int((opens - datetime.datetime.now(datetime.timezone.utc)).total_seconds()) - 5),
    )
    late = (datetime.datetime.now(datetime.timezone.utc) - opens).total_seconds()
    if late < 0:
        time.sleep(-late)
    woken = time.monotonic()
    lab.trigger(lab.robots)
    reached: dict[str, float] = {}
    deadline = woken + 900
    while len(reached) < len(lab.robots) and time.monotonic() < deadline:
        for robot, report in op.reports().items():
            if (
                robot in lab.robots
                and robot not in reached
                and (report.get("applied") or {}).get("version", 0) >= version
                and (report.get("status") or {}).get("health") == "healthy"
            ):
                reached[robot] = time.monotonic() - woken
        time.sleep(1)
    applying = [
        line
        for robot in lab.robots
        for line in journal(lab, robot)
        if line["result"] == "applied" and line["version"] == str(version)
    ]
    wakes = [float(line["seconds"]) for line in applying]
    switched = [s for s in map(until_switched, applying) if s is not None]
    return {
        "prefetch": prefetch,
        "robots": len(lab.robots),
        "before_window": said,
        "late_s": max(0.0, late),
        "reached": len(reached),
        "to_healthy": sorted(reached.values()),
        "applying_wake_s": sorted(wakes),
        "switched_s": sorted(switched),
        "phases": [phases(line) for line in applying],
        "window": window,
        "load": load,
        "idle": idle,
    }


def until_switched(line: dict) -> float | None:
    """An applying wake's seconds up to the end of its prepared switch (the
    payload healthy on the release): its seconds less its phases after the
    switch; None for a wake without one (pure)."""
    found = phases(line)
    if "switch" not in found:
        return None
    after = list(found)[list(found).index("switch") + 1 :]
    return round(float(line["seconds"]) - sum(found[name] for name in after), 2)


def compare(runs: list[dict]) -> dict:
    """Median of each mode's applying wakes and times to healthy (pure)."""
    found = {}
    for mode, prefetched in (("prefetched", True), ("nothing prefetched", False)):
        mine = [r for r in runs if r["prefetch"] is prefetched]
        wakes = [s for r in mine for s in r["applying_wake_s"]]
        healthy = [s for r in mine for s in r["to_healthy"]]
        switched = [s for r in mine for s in r.get("switched_s", [])]
        found[mode] = {
            "runs": len(mine),
            "applying_wake_s": statistics.median(wakes) if wakes else None,
            "switched_s": statistics.median(switched) if switched else None,
            "to_healthy_s": statistics.median(healthy) if healthy else None,
            "phases_s": median_phases([p for r in mine for p in r.get("phases", [])]),
            "all_reached": all(r["reached"] == r["robots"] for r in mine),
            "idle": all(r["idle"] for r in mine),
        }
    return found


def median_phases(found: list[dict[str, float]]) -> dict[str, float]:
    """Each phase's median over the applying wakes that had it (pure)."""
    names = list(dict.fromkeys(name for each in found for name in each))
    return {name: round(statistics.median(e[name] for e in found if name in e), 2) for name in names}


PHASES = ("fetch", "verify", "decide", "prepare", "switch", "load", "deploy", "status", "report")


def markdown(found: dict, conditions: dict) -> str:
    """RESULTS.md's section for ``compare``'s figures (pure)."""

    lines = [
        "## A prefetched release in its maintenance window (issue 35 item 6, issue 38 item 5)",
        "",
        "Written by `python3 -m tests.bench.prefetch`: its own lab, the robots woken at the window's first second "
        '(docs/reference/benchmarks.md, "Prefetch"); seconds, medians over the robots and runs.',
        "",
        *[f"- {k}: {v}" for k, v in conditions.items()],
        "",
        "| mode | window opens -> payload healthy (report) | applying wake | its prepared switch done | runs |",
        "|---|---|---|---|---|",
    ]
    for mode, figures in found.items():
        lines.append(
            f"| {mode} | {cell(figures['to_healthy_s'])} | {cell(figures['applying_wake_s'])} | "
            f"{cell(figures.get('switched_s'))} | {figures['runs']} |"
        )
    lines += [
        "",
        "Where the applying wake's seconds go (its journal line's phases; `load`: the release's Python and roles "
        "starting, `deploy`: the converge's pyinfra run, the payload's switch and health gate included where "
        "nothing was prepared; `switch`: the prepared switch and its health gate):",
        "",
        "| mode | " + " | ".join(PHASES) + " |",
        "|---|" + "---|" * len(PHASES),
    ]
    for mode, figures in found.items():
        phases = figures.get("phases_s") or {}
        lines.append(f"| {mode} | " + " | ".join(cell(phases.get(name)) for name in PHASES) + " |")
    lines += [
        "",
        "Target (issue 38 item 5): window opens -> healthy within the payload's update window plus its health "
        "check: with the prepared switch the payload is healthy when the switch is done (the applying wake up to "
        "its switch); the wake then runs the release's whole converge, and the report follows it "
        '(docs/reference/benchmarks.md, "Prefetch").',
    ]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m tests.bench.prefetch", description=__doc__.split("\n\n")[0])
    parser.add_argument("--prefix", default="pf")
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--runs", type=int, default=3, help="runs of each mode (they alternate)")
    parser.add_argument("--keep", action="store_true", help="leave the lab up")
    parser.add_argument("--no-write", action="store_true", help="print the figures, write nothing")
    args = parser.parse_args(argv)
    from tests.lab import hosts

    runs: list[dict] = []
    try:
        with tempfile.TemporaryDirectory(prefix="bench-prefetch-") as base:
            op, lab = setup(args.prefix, args.robots, Path(base))
            tag = "1.1"
            for index in range(args.runs * 2):
                figures = window_run(lab, op, tag, index % 2 == 0)
                runs.append(figures)
                print(f"bench: window opens -> healthy: {json.dumps(figures)}", flush=True)
                tag = "1.0" if tag == "1.1" else "1.1"
    finally:
        if not args.keep:
            hosts.down(args.prefix)
    found = compare(runs)
    print(json.dumps({"runs": runs, "compare": found}, indent=2))
    conditions = run_conditions(args.robots, **{"every window started idle": all(r["idle"] for r in runs)})
    text = markdown(found, conditions)
    print(text)
    if args.no_write:
        return 0
    if not runs or not conditions["every window started idle"]:
        print("[bench] not written: a window did not start idle; rerun on an idle machine", file=sys.stderr)
        return 1
    sections.write("prefetch", text, {"conditions": conditions, "runs": runs, "compare": found})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
