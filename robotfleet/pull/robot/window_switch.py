"""A release switched to in its maintenance window alone, made ready
before it: converge's ``prepare`` (robotfleet/pull/robot/converge.py), run in
the release's own code.

When a prefetch has put a release in place (robotfleet/pull/robot/prefetch.py),
``prepare`` plans that release's deploy on the robot, ``pyinfra --dry``:
nothing changes, each operation says whether it would.  A role with a
SwitchPart (the payload) is given a file through its setting, and its step
writes there what it would apply instead of applying it.  When no other
operation would change anything, that role makes its request ready
(``payloadctl prepare``: images present, the release written and checked);
otherwise the window runs the release's whole converge, as without it.

``prepare`` also answers the command that switches to it (``{"prepared":
{"role", "target", "switch": argv, "deployment"}}``, the deployment being
the window's, named now).  In the window the agent runs that command
itself (``payloadctl switch``: the same health gate and rollback as an
apply), with no Python of the release to start, then the release's whole
converge as always, under the same deployment: it finds the release in
place, and puts right anything that changed on the robot since the plan.

The plan's conditional operations (``_if=``) are not counted: in every
role they follow another operation's change (``did_change``,
``any_changed``), so with no unconditional change none of them runs.
"""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

from robotfleet.pull.robot import converge

PREPARE_TIMEOUT = 3600


def plan_changes(stdout: str) -> list[str] | None:
    """The operations ``pyinfra --dry --json`` says would change the host
    (their names); None when its output holds no plan (pure)."""
    text = stdout.strip()
    start = text.find("{")
    try:
        plan = json.loads(text[start:])["plan"] if start >= 0 else None
    except (ValueError, KeyError, TypeError):
        return None
    if not isinstance(plan, list):
        return None
    return [str(op.get("name")) for op in plan if isinstance(op, dict) and op.get("hosts_with_change")]


def _not(why: str, took: dict) -> dict:
    return {"prepared": None, "why": why, "took": took}


def prepare(args) -> dict:
    roles, data, pins, run_data, tokens, env = converge._setup(args)
    switching = [role for role in roles if role.switch is not None and role.runs_on(data)]
    requests = {role.name: Path(args.work) / f"{role.name}.switch.json" for role in switching}
    for role in switching:
        run_data[role.switch.setting] = str(requests[role.name])
    converge._write_run_data(args, run_data, tokens)
    started = time.monotonic()
    code, stdout, stderr = converge._pyinfra(["--dry", "--json"], env)
    took = {"plan": round(time.monotonic() - started, 3)}
    (Path(args.work) / "pyinfra.log").write_text(stderr + "\n" + stdout)
    changes = plan_changes(stdout)
    if code or changes is None:
        return _not(f"its plan failed: {'; '.join(converge.errors_of(stderr)) or f'exit {code}'}", took)
    if changes:
        more = f" and {len(changes) - 2} more" if len(changes) > 2 else ""
        return _not(f"it changes more than what runs: {', '.join(changes[:2])}{more}", took)
    written = [role for role in switching if requests[role.name].exists()]
    if not written:
        return _not("nothing to switch", took)
    if len(written) > 1:
        return _not(f"{len(written)} roles would switch ({', '.join(r.name for r in written)})", took)
    role = written[0]
    try:
        done = subprocess.run(
            role.switch.prepare(data, str(requests[role.name])),
            capture_output=True,
            text=True,
            timeout=PREPARE_TIMEOUT,
            stdin=subprocess.DEVNULL,
        )
    except (OSError, subprocess.TimeoutExpired) as error:
        return _not(f"{role.name}: {error}", took)
    finally:
        requests[role.name].unlink(missing_ok=True)
    took["prepare"] = round(time.monotonic() - started - took["plan"], 3)
    said = role.switch.read(done.stdout)
    if said is None:
        tail = [line for line in done.stderr.splitlines() if line.strip()]
        return _not(f"{role.name}: {tail[-1] if tail else f'exit {done.returncode}'}", took)
    if not said["ok"] or not said.get("target") or said.get("outcome") != "prepared":
        return _not(str(said.get("message") or said.get("outcome")), took)
    prepared = {
        "role": role.name,
        "target": said["target"],
        "switch": role.switch.switch(data, said["target"], args.deployment),
        "deployment": args.deployment,
    }
    return {"prepared": prepared, "why": said.get("message"), "took": took}
