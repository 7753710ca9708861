"""Benchmark: reading and checking a large fleet file, as the inventory does
before any connection.  Prints figures; asserts nothing (the target, 5,000
hosts with two sensors each in 1 s, lives here, not in a timed test).

    python3 -m tests.bench.validation [--hosts 5000] [--runs 5]

Each figure is the median of --runs (min–max), in one process after one
untimed run (imports, the settings' checks), with the 1-minute load average
before it (tests/bench/hygiene.py: waited for, marked when above 1.5).  Wall
time on a shared machine swings with other work; CPU time of this process is
printed beside it and is the steadier figure.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import yaml

from robotfleet import deploy_roles
from robotfleet.fleet import validate as fleet
from tests.bench import hygiene

SENSORS = (
    '        - {name: front_camera, subsystem: video4linux, vendor_id: "046d", product_id: "0825", usb_port: "1-1.2"}\n'
    '        - {name: lidar, subsystem: tty, serial: "0001A2B3"}\n'
)


def fleet_text(hosts: int, sensors: bool) -> str:
    """A fleet like inventories/robots.yaml, with ``hosts`` robots."""
    lines = [
        "all:\n  vars:\n    ssh_user: ops\n    payload_image: registry.example.com/acme/ros-payload:1.4.2\n",
        "robots:\n  vars:\n    docker_users: [ops]\n    payload_volumes: [/var/lib/robot-maps:/maps]\n  hosts:\n",
    ]
    for index in range(hosts):
        lines.append(f"    robot{index}:\n      address: 10.{index // 65536}.{index // 256 % 256}.{index % 256}\n")
        if sensors:
            lines.append("      udev_sensors:\n" + SENSORS)
    return "".join(lines)


def measure(path: Path, runs: int) -> tuple[str, str, int, float]:
    fleet.load(path, deploy_roles.registry())
    load = hygiene.wait_for_idle(label=f"validation of {path.name}")
    walls, cpus = [], []
    for _ in range(runs):
        wall, cpu = time.perf_counter(), time.process_time()
        loaded = fleet.load(path, deploy_roles.registry())
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)

    def shown(values):
        return f"{statistics.median(values):.3f} s ({min(values):.3f}–{max(values):.3f})"

    return shown(walls), shown(cpus), len(loaded.hosts("robots")), load


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hosts", type=int, default=5000)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    deploy_roles.registry()  # warm imports once
    with tempfile.TemporaryDirectory() as directory:
        for label, sensors in (("address only", False), ("address + 2 sensors", True)):
            path = Path(directory) / "robots.yaml"
            path.write_text(fleet_text(args.hosts, sensors))
            wall, cpu, count, load = measure(path, args.runs)
            print(
                f"{count} hosts ({label}, {path.stat().st_size // 1024} KiB): "
                f"load + check {wall} wall, {cpu} CPU (median of {args.runs}; load average before: {load:.2f})"
            )
            if not sensors:
                started = time.process_time()
                yaml.load(path.read_text(), Loader=yaml.SafeLoader)
                print(
                    "  for comparison, PyYAML's pure-Python SafeLoader alone: "
                    f"{time.process_time() - started:.3f} s CPU"
                )


if __name__ == "__main__":
    main()
