"""Benchmark: how long a robot is without a working payload.  Prints figures;
asserts nothing.

    python3 -m tests.bench.releases [--prefix bench] [--host robot1] [--keep]

- crash loop -> old release running: from the first start of a crash-looping
  release's container to the start of the old release's container again
  (target <= 10 s with the default settings);
- downtime of a normal update: from the old container's stop to the new
  one's start (target <= 2 s per robot).

Both are read from `docker events` on the robot (nanosecond timestamps), so
the operator's SSH and pyinfra overhead is not counted.  The lab fleet's
health settings apply (inventories/lab.yaml); the failure is detected from the
container's exit/restart, which does not depend on payload_health_timeout.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PYINFRA = "import sys; from pyinfra_cli.main import main; sys.argv[0] = 'pyinfra'; main()"
LAB_TAG = 'payload_image: "@registry@/ros/payload:1.0"'


def fleet(tmp: Path, name: str, host: str, tag: str, crash: bool = False) -> Path:
    text = (ROOT / "inventories" / "lab.yaml").read_text()
    text = text.replace(LAB_TAG, f'payload_image: "@registry@/ros/payload:{tag}"', 1)
    if crash:
        anchor = f"    {host}:\n      sensors:"
        text = text.replace(anchor, f"    {host}:\n      payload_command: [/bin/sh, -c, 'exit 3']\n      sensors:", 1)
    path = tmp / f"{name}.yaml"
    path.write_text(text)
    return path


def deploy(prefix: str, host: str, fleet_file: Path) -> tuple[int, float]:
    env = dict(os.environ, ROBOT_LAB_PREFIX=prefix, ROBOT_LAB_FLEET=str(fleet_file), PYINFRA_PROGRESS="off")
    started = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", PYINFRA, "-y", "inventories/lab.py", "deploy.py", "--limit", host],
                          cwd=ROOT, env=env, capture_output=True, text=True)
    return proc.returncode, time.monotonic() - started


def robot_now(prefix: str, host: str) -> str:
    from tests.lab.state import exec_in

    return exec_in(prefix, host, "date +%s.%N")[1].strip()


def events(prefix: str, host: str, since: str) -> list[dict]:
    from tests.lab.state import exec_in

    until = robot_now(prefix, host)
    code, out = exec_in(prefix, host, (
        f"docker events --since {since} --until {until} --filter type=container"
        " --filter label=com.docker.compose.project=robot-payload --format '{{json .}}'"))
    found = []
    for line in out.splitlines():
        try:
            event = json.loads(line)
        except ValueError:
            continue
        found.append({"action": event.get("Action") or event.get("status"), "time": event["timeNano"] / 1e9,
                      "image": event.get("Actor", {}).get("Attributes", {}).get("image", ""),
                      "id": event.get("id", "")[:12]})
    return found


def crash_loop_recovery(evs: list[dict]) -> float | None:
    """First start of a container that later died -> the last start (the old
    release again)."""
    starts = [e for e in evs if e["action"] == "start"]
    died = {e["id"] for e in evs if e["action"] == "die"}
    crashing = [e for e in starts if e["id"] in died]
    if not crashing or not starts:
        return None
    return starts[-1]["time"] - crashing[0]["time"]


def update_downtime(evs: list[dict]) -> float | None:
    """The old container's stop (die) -> the new one's start."""
    dies = [e for e in evs if e["action"] == "die"]
    starts = [e for e in evs if e["action"] == "start"]
    if not dies or not starts:
        return None
    last_die = dies[0]
    after = [s for s in starts if s["time"] >= last_die["time"]]
    return (after[0]["time"] - last_die["time"]) if after else None


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--prefix", default="bench")
    parser.add_argument("--host", default="robot1")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--keep", action="store_true", help="leave the lab up")
    args = parser.parse_args()
    from tests.lab import hosts

    hosts.up(args.prefix)
    tmp = Path(tempfile.mkdtemp(prefix="bench-releases-"))
    host = args.host
    try:
        code, seconds = deploy(args.prefix, host, fleet(tmp, "base", host, "1.0"))
        print(f"setup deploy of {host} to 1.0: exit {code}, {seconds:.1f} s")
        tags = ["1.1", "1.0"] * args.rounds
        print(f"\n{'measure':40} {'seconds':>8}   (target)")
        for tag in tags:
            since = robot_now(args.prefix, host)
            code, seconds = deploy(args.prefix, host, fleet(tmp, f"to-{tag}", host, tag))
            down = update_downtime(events(args.prefix, host, since))
            print(f"{'update to ' + tag + ' downtime':40} {down if down is None else round(down, 2)!s:>8}   (<= 2)"
                  f"   deploy exit {code}, {seconds:.1f} s wall")
        for round_ in range(args.rounds):
            since = robot_now(args.prefix, host)
            code, seconds = deploy(args.prefix, host, fleet(tmp, "crash", host, "1.0", crash=True))
            back = crash_loop_recovery(events(args.prefix, host, since))
            print(f"{'crash loop -> old release running':40} {back if back is None else round(back, 2)!s:>8}   (<= 10)"
                  f"   deploy exit {code} (a failure is expected), {seconds:.1f} s wall")
    finally:
        if not args.keep:
            hosts.down(args.prefix)
    return 0


if __name__ == "__main__":
    sys.exit(main())
