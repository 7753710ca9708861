"""Benchmark: the old payload's stop inside an update, apart from the rest,
for payloads that stop differently, each with Docker's defaults and with the
settings made for it (issue 29 item 5).  Prints figures; asserts nothing.

    python3 -m tests.bench.stops [--prefix bench] [--host robot1] [--rounds 2]
        [--stops lab,sigint-only,no-trap] [--no-write] [--write-loaded] [--keep]

Writes the stops section of tests/bench/RESULTS.md (and RESULTS-stops.json)
when every sample started on an idle machine (tests/bench/sections.py).

- stop: Docker's first signal to the old container (its `kill` event) ->
  its exit (`die`);
- down: the old container's exit -> the new one's start;
- update: the deploy's wall time; rest: update minus stop.

Read from `docker events` on the robot (nanosecond timestamps), so the
operator's SSH and pyinfra overhead is not in stop and down.  The update
window and the broken releases are tests/bench/releases.py's.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from tests.bench import hygiene, sections
from tests.bench.releases import LAB_TAG, ROOT, deploy
from tests.bench.sections import cell

# How the payload stops: (what it is, the host's settings without and with
# the settings for it).  The lab payload (payload.sh) traps TERM and INT; a
# ROS launch stops on SIGINT only (a shell trapping INT stands in for it:
# as PID 1 it ignores SIGTERM, so Docker kills it after the grace period);
# a shell with no trap at all ignores both as PID 1, an init passes them on.
LOOP = "while :; do touch /tmp/heartbeat; sleep 1 & wait $!; done"
STOPS = {
    "lab": ("the lab payload (payload.sh traps TERM and INT)", {}, {"ros_preset": "ros2"}),
    "sigint-only": (
        "stops on SIGINT only, as roslaunch / ros2 launch",
        {"payload_command": ["/bin/sh", "-c", f"trap 'exit 0' INT; {LOOP}"]},
        {"payload_command": ["/bin/sh", "-c", f"trap 'exit 0' INT; {LOOP}"], "ros_preset": "ros2"},
    ),
    "no-trap": (
        "a shell entrypoint with no trap",
        {"payload_command": ["/bin/sh", "-c", LOOP]},
        {"payload_command": ["/bin/sh", "-c", LOOP], "payload_init": True},
    ),
}


def fleet(tmp: Path, name: str, host: str, tag: str, settings: dict | None = None) -> Path:
    text = (ROOT / "inventories" / "lab.yaml").read_text()
    text = text.replace(LAB_TAG, f'payload_image: "@registry@/ros/payload:{tag}"', 1)
    settings = dict(settings or {})
    if settings:
        anchor = f"    {host}:\n      udev_sensors:"
        lines = "".join(f"      {key}: {json.dumps(value)}\n" for key, value in settings.items())
        text = text.replace(anchor, f"    {host}:\n{lines}      udev_sensors:", 1)
    path = tmp / f"{name}.yaml"
    path.write_text(text)
    return path


def robot_now(prefix: str, host: str) -> str:
    from tests.lab.state import exec_in

    return exec_in(prefix, host, "date +%s.%N")[1].strip()


def events(prefix: str, host: str, since: str) -> list[dict]:
    from tests.lab.state import exec_in

    until = robot_now(prefix, host)
    code, out = exec_in(
        prefix,
        host,
        (
            f"docker events --since {since} --until {until} --filter type=container"
            " --filter label=com.docker.compose.project=robot-payload --format '{{json .}}'"
        ),
    )
    found = []
    for line in out.splitlines():
        try:
            event = json.loads(line)
        except ValueError:
            continue
        found.append(
            {
                "action": event.get("Action") or event.get("status"),
                "time": event["timeNano"] / 1e9,
                "image": event.get("Actor", {}).get("Attributes", {}).get("image", ""),
                "id": event.get("id", "")[:12],
            }
        )
    return found


def old_stop(evs: list[dict]) -> float | None:
    """Docker's first signal to the old container (kill) -> its exit (die)."""
    dies = [e for e in evs if e["action"] == "die"]
    if not dies:
        return None
    kills = [e for e in evs if e["action"] == "kill" and e["id"] == dies[0]["id"] and e["time"] <= dies[0]["time"]]
    return dies[0]["time"] - kills[0]["time"] if kills else None


def update_downtime(evs: list[dict]) -> float | None:
    """The old container's stop (die) -> the new one's start."""
    dies = [e for e in evs if e["action"] == "die"]
    starts = [e for e in evs if e["action"] == "start"]
    if not dies or not starts:
        return None
    last_die = dies[0]
    after = [s for s in starts if s["time"] >= last_die["time"]]
    return (after[0]["time"] - last_die["time"]) if after else None


def stop_figures(prefix: str, host: str, tmp: Path, kinds: list[str], rounds: int) -> list[dict]:
    """Each kind of payload, with Docker's defaults and with its settings:
    updates there and back, the old payload's stop apart from the rest."""
    print(f"\n{'payload':50} {'settings':18} {'update':>7} {'stop':>6} {'down':>6} {'rest':>6}   (seconds, medians)")
    found = []
    for kind in kinds:
        what, plain, tuned = STOPS[kind]
        for label, settings in (("Docker's defaults", plain), ("with the settings", tuned)):
            # The stop signal and grace are the old container's: set up with them first.
            deploy(prefix, host, fleet(tmp, f"{kind}-setup", host, "1.0", settings=settings))
            rows, loads = [], []
            for index, tag in enumerate(["1.1", "1.0"] * rounds):
                loads.append(hygiene.wait(f"stop {kind}, {label}, {index}", first=index == 0))
                since = robot_now(prefix, host)
                code, seconds = deploy(prefix, host, fleet(tmp, f"{kind}-{tag}", host, tag, settings=settings))
                evs = events(prefix, host, since)
                rows.append((seconds, old_stop(evs), update_downtime(evs), code))
            cells = [
                statistics.median(v) if v else None
                for v in (
                    [r[0] for r in rows],
                    [r[1] for r in rows if r[1] is not None],
                    [r[2] for r in rows if r[2] is not None],
                    [r[0] - r[1] for r in rows if r[1] is not None],
                )
            ]
            exits = sorted({r[3] for r in rows})
            print(
                f"{what[:50]:50} {label:18} "
                + " ".join(f"{'-' if v is None else round(v, 2)!s:>6}" for v in cells)
                + f"   deploy exits {exits}"
            )
            print(f"{'':50} {'':18} settings: {json.dumps(settings) if settings else '(none)'}")
            stops = [r[1] for r in rows if r[1] is not None]
            found.append(
                {
                    "kind": kind,
                    "payload": what,
                    "settings_label": label,
                    "settings": settings,
                    "update": cells[0],
                    "stop": cells[1],
                    "down": cells[2],
                    "rest": cells[3],
                    "stop_min": min(stops, default=None),
                    "stop_max": max(stops, default=None),
                    "samples": len(rows),
                    "exits": exits,
                    "idle": all(idle for _, idle in loads),
                    "load": max(load for load, _ in loads),
                }
            )
    return found


def markdown(rows: list[dict], conditions: dict) -> str:
    """The stops section of RESULTS.md (pure)."""

    lines = [
        "## The old payload's stop inside an update (issue 29 item 5)",
        "",
        "Written by `python3 -m tests.bench.stops`: one robot updated 1.0 <-> 1.1, times from `docker events` "
        "on the robot (medians; stop: min–max).  stop: Docker's first signal to the old container -> its exit; "
        "down: its exit -> the new one's start; rest: the deploy's wall time without the stop.",
        "",
    ]
    lines += [f"- {k}: {v}" for k, v in conditions.items()]
    lines += [
        "",
        "| payload | settings | update | stop | down | rest | deploy exits | samples |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        settings = (
            ", ".join(f"`{k}: {json.dumps(v)}`" for k, v in row["settings"].items() if k != "payload_command") or "-"
        )
        stop = cell(row["stop"]) + (
            f" ({cell(row['stop_min'])}–{cell(row['stop_max'])})" if row["stop_min"] is not None else ""
        )
        mark = "" if row["idle"] else f" [load {row['load']:.1f}]"
        lines.append(
            f"| {row['payload']} | {row['settings_label']}: {settings} | {cell(row['update'])} | "
            f"{stop}{mark} | {cell(row['down'])} | {cell(row['rest'])} | {row['exits']} | {row['samples']} |"
        )
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(
        prog="python3 -m tests.bench.stops",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--prefix", default="bench")
    parser.add_argument("--host", default="robot1")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument(
        "--stops",
        default="lab,sigint-only,no-trap",
        help=f"kinds of payload whose stop to time, of: {', '.join(STOPS)}",
    )
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--write-loaded", action="store_true", help="write even figures taken under load (marked)")
    parser.add_argument("--keep", action="store_true", help="leave the lab up")
    args = parser.parse_args()
    kinds = [k for k in args.stops.split(",") if k]
    unknown = [k for k in kinds if k not in STOPS]
    if unknown:
        parser.error(f"--stops: no such kind {', '.join(unknown)} (kinds: {', '.join(STOPS)})")
    from tests.lab import hosts

    host = args.host
    number = "".join(ch for ch in host if ch.isdigit())
    hosts.up(args.prefix, robots=int(number or 1), laptops=0)  # up to the robot measured
    tmp = Path(tempfile.mkdtemp(prefix="bench-stops-"))
    try:
        rows = stop_figures(args.prefix, host, tmp, kinds, args.rounds)
        deploy(args.prefix, host, fleet(tmp, "base", host, "1.0"))  # the lab as it was
    finally:
        if not args.keep:
            hosts.down(args.prefix)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    conditions = {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "commit": commit.stdout.strip(),
        "cpus": os.cpu_count(),
        "robot": host,
        "updates per row": 2 * args.rounds,
    }
    text = markdown(rows, conditions)
    print(text)
    if args.no_write:
        return 0
    if not all(row["idle"] for row in rows) and not args.write_loaded:
        print(
            "[bench] not written: some samples did not start idle (see [load X]); rerun on an idle machine, "
            "or pass --write-loaded",
            file=sys.stderr,
        )
        return 1
    sections.write("stops", text, {"conditions": conditions, "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
