"""Fleet status: what each host runs and whether it is healthy.

    python3 -m roles.status inventories/robots.py [--limit robot2] [--json]

One row per host: reachable, Docker version, current release, image digest,
container state and health, previous release, time of the last deploy.
Unreachable hosts are rows too, never an abort.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import os
import re
import shlex
import sys

import gevent

from roles import waves

COLUMNS = [
    ("host", "HOST"),
    ("reachable", "REACHABLE"),
    ("docker", "DOCKER"),
    ("release", "RELEASE"),
    ("image", "IMAGE"),
    ("state", "STATE"),
    ("health", "HEALTH"),
    ("previous", "PREVIOUS"),
    ("deployed", "LAST DEPLOY"),
    ("lock", "LOCK"),
    ("gpu_driver", "GPU DRIVER"),
    ("gpu_runtime", "GPU RUNTIME"),
    ("rollout", "ROLLOUT"),
]


def status_command(data) -> str:
    from roles.payload import HELPER

    q = shlex.quote
    return (
        f"if [ -x {HELPER} ]; then /usr/bin/python3 {HELPER} status --dir {q(data.payload_dir)}"
        f" --name {q(data.payload_name)} --lock-file {q(data.payload_lock_file)}; "
        "else printf '{\"docker_version\": \"%s\"}\\n' \"$(docker version -f '{{.Server.Version}}' 2>/dev/null)\"; fi; "
        + gpu_status_command(data)
    )


def gpu_status_command(data) -> str:
    """One line: 'gpu<TAB><the driver version file's first line><TAB>yes|no'
    (yes: Docker lists the nvidia runtime)."""
    path = shlex.quote(data.get("gpu_driver_version_file") or "/proc/driver/nvidia/version")
    return (
        f"printf 'gpu\\t%s\\t%s\\n' \"$(head -n 1 {path} 2>/dev/null)\" "
        "\"$(docker info -f '{{json .Runtimes}}' 2>/dev/null | grep -q '\"nvidia\"' && echo yes || echo no)\""
    )


def parse_report(stdout: str) -> dict:
    """payloadctl's JSON status plus the GPU line (pure)."""
    report, gpu = None, {}
    for line in stdout.splitlines():
        if line.startswith("gpu\t"):
            _, driver, runtime = (line.split("\t") + ["", ""])[:3]
            gpu = {"gpu_driver_line": driver, "gpu_runtime": runtime.strip() == "yes"}
        elif report is None and line.strip().startswith("{"):
            report = json.loads(line)
    if report is None:
        raise ValueError("no status report")
    return {**report, **gpu}


def row(name: str, report: dict | None, error: str | None = None) -> dict:
    """A table row from payloadctl's status report (pure)."""
    if report is None:
        return {"host": name, "reachable": False, "error": error}
    current = report.get("current") or {}
    previous = report.get("previous") or {}
    containers = report.get("containers") or []
    images = [i.get("pinned") for i in (current.get("images") or {}).values()]
    return {
        "host": name,
        "reachable": True,
        "docker": report.get("docker_version") or None,
        "release": current.get("id"),
        "image": images[0] if len(images) == 1 else (", ".join(images) or None),
        "state": ", ".join(c["status"] for c in containers) or None,
        "health": ", ".join(c.get("health") or "none" for c in containers) or None,
        "restarts": sum(c.get("restarts", 0) for c in containers),
        "previous": previous.get("id"),
        "deployed": current.get("rolled_back_to") or current.get("activated") or current.get("created"),
        "release_state": current.get("state"),
        "lock": report.get("update_lock"),
        "rolled_back_from": current.get("rolled_back_from"),
        **_gpu_cells(report),
        **per_service(report.get("services") or {}),
        "image_refs": sorted(current.get("images") or {}),
    }


def per_service(services: dict) -> dict:
    """A project of several services: each one's image, state and health
    (the table's columns name the service; --json has them whole)."""
    if len(services) < 2:
        return {"services": services or None} if services else {}
    ordered = sorted(services.items())
    return {
        "services": services,
        "image": ", ".join(f"{name}={s.get('image')}" for name, s in ordered),
        "state": ", ".join(f"{name}:{s.get('state')}" for name, s in ordered),
        "health": ", ".join(f"{name}:{s.get('health') or 'none'}" for name, s in ordered),
    }


def _gpu_cells(report: dict) -> dict:
    from roles.gpu import plan as gpu_plan

    driver = gpu_plan.driver_version(report.get("gpu_driver_line") or "")
    runtime = report.get("gpu_runtime")
    # A host with neither a driver nor the runtime is not a GPU host: "-", not "no".
    return {"gpu_driver": driver, "gpu_runtime": runtime if (driver or runtime) else None}


def table(rows: list[dict]) -> str:
    def cell(value):
        if value is True:
            return "yes"
        if value is False:
            return "no"
        return "-" if value in (None, "") else str(value)

    def short(key, value):
        # The table shows the first 12 digits of a digest; --json has it whole.
        if key == "image" and isinstance(value, str) and "@sha256:" in value:
            return re.sub(r"@sha256:([0-9a-f]{12})[0-9a-f]{52}", r"@sha256:\1", value)
        return value

    cells = [[cell(short(key, r.get(key))) for key, _ in COLUMNS] for r in rows]
    widths = [max([len(title)] + [len(c[i]) for c in cells]) for i, (_, title) in enumerate(COLUMNS)]
    lines = ["  ".join(title.ljust(w) for (_, title), w in zip(COLUMNS, widths)).rstrip()]
    lines += ["  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in cells]
    return "\n".join(lines)


def collect(inventory_path: str, limits: list[str]) -> list[dict]:
    from pyinfra.api import Config, State
    from pyinfra.api.connect import connect_all
    from pyinfra.api.exceptions import PyinfraError
    from pyinfra.context import ctx_state
    from pyinfra_cli.inventory import make_inventory

    with ctx_state.use(State()):
        inventory = make_inventory(inventory_path, cwd=os.getcwd())
    hosts = [h for h in inventory if not limits or any(
        fnmatch.fnmatch(h.name, pattern) or pattern in h.groups for pattern in limits
    )]
    state = State(inventory=inventory, config=Config(CONNECT_TIMEOUT=10), check_for_changes=False)
    state.limit_hosts = hosts
    with ctx_state.use(state):
        try:
            connect_all(state)
        except PyinfraError:
            pass  # every host unreachable: each still gets its row
        return _read_status(hosts)


def _read_status(hosts) -> list[dict]:
    from pyinfra.api.command import StringCommand

    def one(host):
        if not host.connected:
            return row(host.name, None, "cannot connect")
        ok, output = host.run_shell_command(StringCommand(status_command(host.data)), _sudo=True)
        if not ok:
            return {**row(host.name, {}), "error": output.stderr.strip()[-200:]}
        try:
            return row(host.name, parse_report(output.stdout))
        except ValueError:
            return {**row(host.name, {}), "error": "unreadable status"}

    jobs = [gevent.spawn(one, host) for host in hosts]
    gevent.joinall(jobs)
    return [job.value for job in jobs]


def main(argv=None) -> int:
    # Hosts are queried in parallel greenlets over paramiko; patching is the
    # command's business, not its importers' (the unit tests import this module).
    from gevent import monkey

    monkey.patch_all()
    parser = argparse.ArgumentParser(prog="python3 -m roles.status", description=__doc__.splitlines()[0])
    parser.add_argument("inventory")
    parser.add_argument("--limit", action="append", default=[], help="host name pattern or group")
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    args = parser.parse_args(argv)
    if not os.path.exists(args.inventory):
        print(f"{args.inventory}: no such inventory file", file=sys.stderr)
        return 2
    rows = collect(args.inventory, args.limit)
    rollout = waves.latest_state()
    for r in rows:
        r["rollout"] = waves.host_state(rollout, r["host"])
    if args.json:
        print(json.dumps(rows, indent=2, sort_keys=True))
    else:
        print(table(rows))
        if rollout:
            print(waves.summary(rollout))
    return 0 if all(r["reachable"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
