"""Benchmark: checking a fleet file before connecting, with the Compose
Specification schema (issue 13).  Prints figures; asserts nothing.

    python3 -m tests.bench.fleet_check [--hosts 1000]

Hosts of a group mostly share one project, so each distinct compose document
is validated once; the first check also loads the schema and jsonschema.
"""

from __future__ import annotations

import argparse
import time

REG = "registry.example.com/acme"


def fleet(hosts: int, services: bool) -> dict:
    if not services:
        return {
            "robots": {
                "hosts": {
                    f"robot{i}": {"address": f"10.0.{i // 250}.{i % 250}", "payload_image": f"{REG}/payload:1.0"}
                    for i in range(hosts)
                }
            }
        }
    group = {
        "payload_services": {
            "driver": {"image": f"{REG}/driver:2.0", "devices": [], "cap_add": ["SYS_NICE"], "ulimits": {"rtprio": 99}},
            "slam": {"image": f"{REG}/slam:1.0", "shm_size": "1g", "volumes": ["/srv/maps:/maps"]},
        },
        "ros_preset": "ros2",
    }
    hosts_data = {
        f"robot{i}": {
            "address": f"10.0.{i // 250}.{i % 250}",
            "payload_services": {"slam": {"image": f"{REG}/slam:1.{i % 4}"}},
        }
        for i in range(hosts)
    }
    return {"robots": {"vars": group, "hosts": hosts_data}}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--hosts", type=int, default=1000)
    args = parser.parse_args()
    started = time.perf_counter()
    from robotfleet import deploy_roles
    from robotfleet.fleet import validate as fleet_module
    from roles.payload import problems as services

    registry = deploy_roles.registry()
    services.compose_schema()
    services._validator()
    print(f"import + schema load: {time.perf_counter() - started:.3f} s")
    for label, with_services in (("single image", False), ("two services, ROS 2 preset", True)):
        doc = fleet(args.hosts, with_services)
        services._schema_problems.cache_clear()
        t = time.perf_counter()
        fleet_module.check(doc, "bench.yaml", registry)
        seconds = time.perf_counter() - t
        print(f"{label}: {args.hosts} hosts checked in {seconds:.3f} s ({seconds / args.hosts * 1000:.2f} ms/host)")


if __name__ == "__main__":
    main()
