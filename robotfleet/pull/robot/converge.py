"""One converge run of a pull robot, in the release's own code: run by the
agent (robotfleet/pull/robot/agent.py) as a separate process from the verified
deploy tree, so the release's code runs its own deploy and reads its own
status.

    python -m robotfleet.commands.converge run --robot R --fleet F --record release.json --deployment D --work DIR
    python -m robotfleet.commands.converge status --robot R --fleet F
    python -m robotfleet.commands.converge prepare (as run)

``run`` holds each role's lock for the whole run (``Role.hold``: the
payload's apply lock, with a token its own apply joins), runs the same
deploy the operator runs, ``pyinfra -y --json inventories/pull.py
deploy.py`` on @local, with the release's image pins, then reads the
roles' status on the robot.  Both print one JSON line: {"exit", "row",
"results", "missing", "errors", "log", "watch", "took"} (``took``: the
deploy's and the status read's seconds; ``status``: "row",
"missing" and "watch": the roles' watched paths as they were just before
the status was read, robotfleet/pull/protocol/path_signatures.py ``watched``).
The agent depends only on that line and these arguments, which every
release keeps.

``prepare`` makes a release ready for its maintenance window
(robotfleet/pull/robot/window_switch.py says when and why): it plans the
deploy (``pyinfra --dry``, nothing changed) with each role's SwitchPart
setting naming a file; when the plan changes nothing and one role wrote
its request there, that role makes it ready (``{"prepared": {"role",
"target", "switch", "deployment"} or null, "why"}``; ``--deployment``: the
window's).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from robotfleet import CHECKOUT, deploy_roles, status_parts
from robotfleet.pull.protocol import agent_files
from robotfleet.pull.protocol import record as records
from robotfleet.pull.protocol.path_signatures import watched
from robotfleet.pull.protocol.robot_data import DataError, HostData, host_data, pin_settings
from robotfleet.role import DEPLOYMENT_ENV

PYINFRA_TIMEOUT = 4 * 3600
STATUS_TIMEOUT = 120


class ConvergeError(Exception):
    """The run could not start (one line)."""


def watch(roles, data) -> dict[str, str]:
    """What the roles' watched paths look like now (taken before their
    status is read: a change during the read shows at the next check)."""
    return watched(
        path
        for role in roles
        if role.status and role.status.watch and role.runs_on(data)
        for path in role.status.watch(data)
    )


def status_row(robot: str, roles, data) -> dict:
    """The roles' status of this robot, read here as `robotfleet status` reads it over SSH."""
    command = status_parts.status_command(roles, data)
    try:
        done = subprocess.run(["sh", "-c", command], capture_output=True, text=True, timeout=STATUS_TIMEOUT)
    except subprocess.TimeoutExpired:
        return {**status_parts.row(robot, roles, {}), "error": f"status took more than {STATUS_TIMEOUT} s"}
    return status_parts.row(robot, roles, status_parts.sections(done.stdout))


def missing(roles, data, row: dict) -> list[dict]:
    """What the robot does not run as the roles want it, healthy (one line each)."""
    found = []
    for role in roles:
        if role.rollout is not None and role.runs_on(data):
            why = role.rollout.missing(row, role.rollout.target(data))
            if why:
                found.append({"role": role.name, "why": why})
    return found


def results(roles, data, row: dict, deployment: str) -> list[dict]:
    """Each role's own structured result of this run, when it recorded one;
    ``outcome`` is the role's word for it where its result names one."""
    found = []
    for role in roles:
        if role.rollout is None or role.rollout.result is None or not role.runs_on(data):
            continue
        said = role.rollout.result(row, deployment)
        if said is None:
            continue
        outcome = next(
            (
                cell.get("outcome")
                for cell in row.values()
                if isinstance(cell, dict) and cell.get("deployment") == deployment
            ),
            None,
        )
        found.append({"role": role.name, "ok": said[0], "why": said[1], "outcome": outcome})
    return found


def errors_of(stderr: str, limit: int = 3) -> list[str]:
    """pyinfra's lines that say why the run failed."""
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    picked = [line for line in lines if "rror" in line or "failed" in line.lower()]
    return (picked or lines)[-limit:]


def _setup(args):
    """(roles, data, pins, run data, tokens, env) of a run: its data (the
    release's pins, who it is for) goes to its work directory's run.json
    (_write_run_data), where the pull inventory reads it."""
    roles = deploy_roles.roles()
    data = host_data(args.robot, args.fleet, deploy_roles.registry())
    record = records.parse(Path(args.record).read_bytes())
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True, mode=0o700)
    pins = pin_settings(roles, record, args.robot)
    run_data = {
        **pins,
        agent_files.AGENT_RUN: {"robot": args.robot, "version": record.version, "release": record.release},
    }
    tokens = {}
    env = dict(
        os.environ,
        ROBOT_FLEET=str(Path(args.fleet).resolve()),
        ROBOT_FLEET_HOST=args.robot,
        ROBOT_PULL_DATA=str(work / "run.json"),
        PYINFRA_PROGRESS="off",
        PYTHONPATH=str(CHECKOUT),
        **{DEPLOYMENT_ENV: args.deployment},
    )
    return roles, data, pins, run_data, tokens, env


def _write_run_data(args, run_data: dict, tokens: dict) -> None:
    (Path(args.work) / "run.json").write_text(json.dumps({"data": run_data, "tokens": tokens}))


def _pyinfra(arguments: list[str], env: dict, prefix=()) -> tuple[int, str, str]:
    command = [*prefix, sys.executable, "-m", "pyinfra", *arguments, "inventories/pull.py", "deploy.py"]
    try:
        done = subprocess.run(command, cwd=CHECKOUT, env=env, capture_output=True, text=True, timeout=PYINFRA_TIMEOUT)
        return done.returncode, done.stdout, done.stderr
    except subprocess.TimeoutExpired as error:
        return 124, error.stdout or "", (error.stderr or "") + "\npyinfra: timed out"


def _outcome(args, roles, data, pins: dict) -> dict:
    """The roles' status read now, and what it says of this run."""
    watched = watch(roles, data)
    row = status_row(args.robot, roles, data)
    # What the robot must run is the release's images by the digests it pinned, as the deploy was given them.
    pinned = HostData({**data, **pins})
    return {
        "row": row,
        "watch": watched,
        "results": results(roles, data, row, args.deployment),
        "missing": missing(roles, pinned, row),
    }


def run(args) -> dict:
    roles, data, pins, run_data, tokens, env = _setup(args)
    prefix = []
    for role in roles:
        if role.hold is not None and role.runs_on(data):
            token_file = str(Path(args.work) / f"{role.name}.token")
            held = role.hold.command(data, token_file)
            if held:
                prefix += held
                tokens[role.hold.setting] = token_file
    _write_run_data(args, run_data, tokens)
    started = time.monotonic()
    code, stdout, stderr = _pyinfra(["-y", "--json"], env, prefix)
    log = Path(args.work) / "pyinfra.log"
    log.write_text(stderr + "\n" + stdout)
    deployed = time.monotonic()
    found = _outcome(args, roles, data, pins)
    took = {"deploy": round(deployed - started, 3), "status": round(time.monotonic() - deployed, 3)}
    errors = errors_of(stderr) if code else []
    return {"exit": code, **found, "errors": errors, "log": str(log), "took": took}


def status(args) -> dict:
    roles = deploy_roles.roles()
    data = host_data(args.robot, args.fleet, deploy_roles.registry())
    watched = watch(roles, data)
    row = status_row(args.robot, roles, data)
    return {"row": row, "missing": missing(roles, data, row), "watch": watched}


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="python -m robotfleet.commands.converge")
    sub = top.add_subparsers(dest="action", required=True)
    for name in ("run", "status", "prepare"):
        each = sub.add_parser(name)
        each.add_argument("--robot", required=True)
        each.add_argument("--fleet", required=name != "status")
        if name != "status":
            each.add_argument("--record", required=True)
            each.add_argument("--deployment", required=True)
            each.add_argument("--work", required=True)
    return top


def main(argv=None, more=None) -> int:
    """``more``: the other actions (prepare: robotfleet/pull/robot/window_switch.py)."""
    args = parser().parse_args(argv)
    try:
        actions = {"run": run, "status": status, **(more or {})}
        if args.action not in actions:
            raise ConvergeError(f"this entry point has no {args.action!r}")
        found = actions[args.action](args)
    except (ConvergeError, DataError, records.RecordError, OSError) as error:
        found = {"error": str(error)}
    print(json.dumps(found, sort_keys=True, default=str))
    return 0
