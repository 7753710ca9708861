"""Benchmark: how long one robot is without a working payload.  Prints
figures; asserts nothing.

    python3 -m tests.bench.releases [--prefix bench] [--robots 1] [--host robot1] [--rounds 3] [--keep]

On one robot of its own lab, the others idle (a robot with its CPU to
itself, as a real one has), each figure the median of --rounds samples
with its spread:

- update window: the old container's last moment running (FinishedAt) ->
  the new one's first (StartedAt), updating 1.0 <-> 1.1 (target <= 0.5 s);
- a release that exits at once (payload_command `exit 3`): Docker's
  verdict (the container's exit) -> the old release running, and its first
  start -> the old release running;
- a release that runs but never turns healthy (tag 1.2-broken): Docker's
  `unhealthy` verdict -> the old release running (target <= 0.5 s: what the
  tool adds), and its first start -> the old release running (mostly the
  image's health check: interval x retries, printed beside it).

Every time is Docker's own, read on the robot (tests/bench/window.py), so
the operator's SSH and pyinfra overhead is not counted.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from tests.bench import hygiene, window
from tests.fixtures import pyinfra

ROOT = Path(__file__).resolve().parents[2]
LAB_TAG = 'payload_image: "@registry@/ros/payload:1.0"'


def fleet(tmp: Path, name: str, host: str, tag: str, command: str | None = None) -> Path:
    text = (ROOT / "inventories" / "lab.yaml").read_text()
    text = text.replace(LAB_TAG, f'payload_image: "@registry@/ros/payload:{tag}"', 1)
    if command:
        anchor = f"    {host}:\n      udev_sensors:"
        text = text.replace(anchor, f"    {host}:\n      payload_command: {command}\n      udev_sensors:", 1)
    path = tmp / f"{name}.yaml"
    path.write_text(text)
    return path


def deploy(prefix: str, host: str, fleet_file: Path) -> tuple[int, float]:
    env = dict(os.environ, ROBOT_LAB_PREFIX=prefix, ROBOT_LAB_FLEET=str(fleet_file), PYINFRA_PROGRESS="off")
    started = time.monotonic()
    proc = pyinfra("-y", "inventories/lab.py", "deploy.py", "--limit", host, env=env, timeout=None)
    return proc.returncode, time.monotonic() - started


def main() -> int:
    parser = argparse.ArgumentParser(
        prog="python3 -m tests.bench.releases",
        description=__doc__.split("\n\n")[0],
        epilog="The window of each of 10 robots updated at once: python3 -m tests.bench "
        "--robots 10 --updates-at 10 --fresh-at (see its --help).",
    )
    parser.add_argument("--prefix", default="bench")
    parser.add_argument("--host", default="robot1")
    parser.add_argument("--robots", type=int, default=1, help="robots in the lab (the others idle)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--keep", action="store_true", help="leave the lab up")
    args = parser.parse_args()
    from tests.lab import hosts
    from tests.lab.state import exec_in

    hosts.up(args.prefix, robots=args.robots, laptops=0)
    tmp = Path(tempfile.mkdtemp(prefix="bench-releases-"))
    host = args.host

    def sh(command: str) -> str:
        return exec_in(args.prefix, host, command)[1]

    figures: dict[str, hygiene.Figure] = {}

    def sample(name: str, value: float | None, load: float, idle: bool) -> None:
        if value is not None:
            figures.setdefault(name, hygiene.Figure()).add(value, load, idle)

    try:
        code, seconds = deploy(args.prefix, host, fleet(tmp, "base", host, "1.0"))
        print(f"setup deploy of {host} to 1.0: exit {code}, {seconds:.1f} s", flush=True)
        for index, tag in enumerate(["1.1", "1.0"] * args.rounds):
            load, idle = hygiene.wait(f"update to {tag}", first=index == 0)
            with window.Watch(sh) as watch:
                code, seconds = deploy(args.prefix, host, fleet(tmp, f"to-{tag}", host, tag))
            sample("update window", watch.window(), load, idle)
            print(f"update to {tag}: window {watch.window()}, deploy exit {code}, {seconds:.1f} s wall", flush=True)
        settings = {}
        for kind, (tag, command) in window.BROKEN.items():
            for index in range(args.rounds):
                load, idle = hygiene.wait(f"broken release ({kind})", first=index == 0)
                with window.Watch(sh) as watch:
                    code, seconds = deploy(args.prefix, host, fleet(tmp, f"broken-{index}", host, tag, command))
                found = watch.broken() or {}
                print(
                    f"broken release ({kind}): {found}, deploy exit {code} (a failure is expected), "
                    f"{seconds:.1f} s wall",
                    flush=True,
                )
                sample(f"{kind}: verdict -> old release running", found.get("verdict_to_old_running"), load, idle)
                sample(
                    f"{kind}: first start -> old release running", found.get("first_start_to_old_running"), load, idle
                )
                settings[kind] = f"verdict: {found.get('verdict', '?')}; " + window.health_settings(
                    sh, tag, (ROOT / "inventories" / "lab.yaml").read_text()
                )
        print(f"\n{'figure (one robot, seconds)':58} {'median (min-max)':>24}")
        for name, figure in figures.items():
            print(f"{name:58} {hygiene.shown(figure.as_dict()):>24}")
        for kind, text in settings.items():
            print(f"{kind}: {text}")
    finally:
        if not args.keep:
            hosts.down(args.prefix)
    return 0


if __name__ == "__main__":
    sys.exit(main())
