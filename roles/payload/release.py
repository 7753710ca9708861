"""A release on the robot: the spec the deploy hands payloadctl, whether a
release is needed, and the commands that run payloadctl on the robot (as a
transient systemd unit, so a dropped SSH link cannot leave it half-switched)
and read its structured result (payloadctl/results.py): what the operator
sees of a run is said from the result, never parsed from printed lines."""

from __future__ import annotations

import datetime
import getpass
import json
import os
import secrets
import shlex
import socket

from pyinfra import host, logger
from pyinfra.api import FunctionCommand, deploy
from pyinfra.api.arguments import CONNECTOR_ARGUMENT_KEYS
from pyinfra.api.util import format_text, print_host_combined_output

import roles.payload.compose as compose
import roles.payload.takeover_plan as takeover_plan
from robotfleet.checkers import one_line
from robotfleet.host import operations
from robotfleet.host.snapshot import Snapshot
from robotfleet.role import deployment
from roles.payload.installed_files import HELPER
from roles.payload.payloadctl import lock, results
from roles.payload.payloadctl.lifecycle import SETTLED
from roles.payload.payloadctl.spec import Spec


def spec(data, doc: dict, checks: list = ()) -> Spec:
    """What the release is, as payloadctl keeps it with the release."""
    return Spec(
        name=data.payload_name,
        dir=data.payload_dir,
        compose=doc,
        spec_hash=compose.spec_hash(doc, data.payload_autostart),
        autostart=data.payload_autostart,
        delivery=data.payload_delivery,
        health_timeout=data.payload_health_timeout,
        stable_seconds=data.payload_stable_seconds,
        pull_timeout=data.payload_pull_timeout,
        apply_lock_timeout=data.payload_apply_lock_timeout,
        keep_releases=data.payload_keep_releases,
        lock_file=data.payload_update_lock_path,
        checks=[check for check in checks if check],  # run in each container once healthy
        takeover=takeover_plan.takeover_of(data),
    )


def operator() -> str:
    return f"{getpass.getuser()}@{socket.gethostname()}"


def request(data, doc: dict, checks: list) -> str:
    """What `payloadctl apply` reads: the spec, who asks, the deployment
    that asks (named in the result) and the apply lock's token of the run
    this deploy is part of (payload_lock_token: sent on stdin, never shown)."""
    run = {
        "by": f"{operator()} (pyinfra)",
        "force": bool(data.payload_force),
        "host": host.name,
        "deployment": deployment(),
    }
    if data.payload_lock_token:
        run["lock_token"] = data.payload_lock_token
    return json.dumps({"spec": spec(data, doc, checks).to_dict(), "run": run}, sort_keys=True)


def read_result(lines) -> dict | None:
    """payloadctl's structured result among a command's output lines (the
    last JSON line of its format), or None (pure)."""
    for line in reversed(list(lines)):
        line = line.strip()
        if not line.startswith("{"):
            continue
        try:
            found = json.loads(line)
        except ValueError:
            continue
        if isinstance(found, dict) and found.get("payloadctl") == results.FORMAT and isinstance(found.get("ok"), bool):
            return found
    return None


def said(result: dict) -> list[tuple[str, str]]:
    """What the operator is told of a result (pure): (level, one line)
    each container it stopped and why, then its line if it is not ok."""
    lines = []
    for c in result.get("taken_over") or ():
        if isinstance(c, dict):
            where = f"compose project {c.get('project')}, " if c.get("project") else ""
            lines.append(("warning", f"payload: stopped {c.get('name')} ({where}{c.get('image')}): {c.get('why')}"))
    if not result["ok"]:
        lines.append(("error", str(result.get("message") or result.get("reason") or "payload: failed")))
    return [(level, one_line(text)) for level, text in lines]


def payloadctl_command(script: str, stdin: list[str] | None = None) -> FunctionCommand:
    """``script`` (which ends in `payloadctl result`) run on the robot; its
    structured result decides the run and what is said.  Without one (the
    script failed before payloadctl), its own output is shown."""
    command = operations.shell(script, stdin)
    arguments = {
        key: value for key, value in (host.current_op_global_arguments or {}).items() if key in CONNECTOR_ARGUMENT_KEYS
    }
    arguments.update(command.connector_arguments)

    def run(state, host):
        status, output = host.run_shell_command(command, print_output=state.print_output, **arguments)
        result = read_result(output.stdout_lines)
        if result is None:
            if status is False and not state.print_output:
                print_host_combined_output(host, output)
            return status
        for level, text in said(result):
            if level == "error":
                logger.error(f"{host.print_prefix}{format_text(text, 'red')}")
            else:
                logger.warning(f"[{host.name}] {text}")
        return bool(status) and result["ok"]

    return FunctionCommand(run, (), {})


def current_record(snap: Snapshot) -> dict:
    try:
        record = json.loads(snap.probes.get("payload_record") or "{}")
    except ValueError:
        return {}
    return record if isinstance(record, dict) else {}


def containers_running(probe_output: str) -> bool:
    """From `docker ps` (the containers probe's own lines, containers.part):
    the payload's containers exist, all run, none is
    unhealthy (a oneshot unit stays "active" when they are gone)."""
    lines = [line.split("\t", 1) for line in probe_output.splitlines() if line.strip()]
    return bool(lines) and all(
        state == "running" and "(unhealthy)" not in (rest[0] if rest else "") for state, *rest in lines
    )


def release_needed(record: dict, wanted_hash: str, autostart: bool, running: bool) -> bool:
    """A release is converged only when it is what was asked, it passed its
    health gate (a failed or interrupted one is tried again) and, where it
    should run, its containers really run."""
    if record.get("spec_hash") != wanted_hash or record.get("state") not in SETTLED:
        return True
    return autostart and not running


def lock_probe(payload_dir: str) -> str:
    """The apply lock holder's note, when the lock is held (read-only)."""
    d = shlex.quote(f"{payload_dir}/{lock.DIR}")
    return f"[ -f {d}/apply.lock ] && ! flock -n {d}/apply.lock true 2>/dev/null && cat {d}/owner.json"


def say_who_holds_the_lock(probe_output: str) -> None:
    """A boot recovery or another deploy holds the robot's apply lock: this
    run's release will wait for it (up to payload_apply_lock_timeout); say so now."""
    if not probe_output.strip():
        return
    try:
        holder = json.loads(probe_output)
    except ValueError:
        holder = {}
    logger.warning(f"[{host.name}] {lock.describe(holder if isinstance(holder, dict) else {}, host.name)}; waiting")


def new_run_id() -> str:
    """Names this run's spec, result and transient unit on the robot."""
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%S") + "-" + secrets.token_hex(4)


def run_path(data, run_id: str) -> str:
    """This run's own directory on the robot (spec and result): two deploys
    at once never share a file."""
    return f"{data.payload_dir}/runs/{run_id}"


def on_robot(data, action: str, arguments: str, run_id: str, prelude: str = "", unit: str | None = None) -> str:
    """Run ``payloadctl <action> <arguments>`` as a transient systemd unit (so
    it goes on if SSH drops), then print the result it recorded for this run
    and exit with it; no result for this run fails the host."""
    q = shlex.quote
    helper = f"/usr/bin/python3 {HELPER}"
    command = f"{helper} {action} {arguments} --run-id {q(run_id)} >/dev/null 2>&1 || true"
    unit_name = f"{data.payload_name}-{unit or action}-{run_id}"
    return (
        f"{prelude}"
        "if command -v systemd-run >/dev/null 2>&1 && [ -d /run/systemd/system ]; then\n"
        f"  systemd-run --quiet --wait --collect --unit={q(unit_name)} {command}\n"
        "else\n"
        f"  {command}\n"
        "fi\n"
        f"exec {helper} result --dir {q(data.payload_dir)} --name {q(data.payload_name)} --run-id {q(run_id)}\n"
    )


def staging_prelude(data, run_id: str, what: str, stdin_to: str | None = None) -> str:
    q = shlex.quote
    directory = run_path(data, run_id)
    fail = f"{{ echo {q(f'payload: cannot write the {what} on this robot (disk full?)')} >&2; exit 1; }}"
    lines = ["umask 077", f"mkdir -p {q(directory)} || {fail}"]
    if stdin_to:
        lines.append(f"cat > {q(directory + '/' + stdin_to)} || {fail}")
    return "\n".join(lines) + "\n"


def apply_script(data, restart: bool, run_id: str) -> str:
    spec_path = shlex.quote(run_path(data, run_id) + "/spec.json")
    prelude = staging_prelude(data, run_id, "spec of this update", "spec.json")
    return on_robot(data, "apply", spec_path + (" --restart" if restart else ""), run_id, prelude, unit="update")


# Where the planning run writes the request on the robot itself: pyinfra's own
# machine (anywhere else the file would be written on the operator's).
WRITES_HERE = ("@local",)


def prepares(data, restart: bool, host_name: str, planning: bool) -> bool:
    """Whether this run writes its release for a window's switch (the pull
    agent's planning run, on the robot itself) instead of applying it: only
    while pyinfra plans (``--dry``); a run that executes (``-y``) applies,
    whatever the setting says.  A release that restarts the unit is applied
    in the window whole."""
    return bool(data.payload_switch_request) and not restart and host_name in WRITES_HERE and planning


def write_request(path: str, text: str) -> None:
    """The request, readable by root alone, written whole (then moved)."""
    temporary = f"{path}.{os.getpid()}"
    descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(descriptor, "w") as handle:
        handle.write(text)
    os.replace(temporary, path)


@operations.operation()
def release(data, document: dict, checks: list, needed: bool, restart: bool):
    """Apply the release on the robot when it is not what runs there."""
    if not needed:
        host.noop("payload release is current")
        return
    if prepares(data, restart, host.name, planning=not host.state.is_executing):
        write_request(data.payload_switch_request, request(data, document, checks))
        host.noop("payload release written for the window's switch")
        return
    run_id = new_run_id()
    yield payloadctl_command(apply_script(data, restart, run_id), stdin=request(data, document, checks).splitlines())


def rollback_script(data, run_id: str) -> str:
    """The previous release comes back with its own spec (payloadctl reads
    it from the release); only who asks, the override and the lock token
    (on stdin, into the run's own 0600 file) are this run's."""
    q = shlex.quote
    arguments = f"--dir {q(data.payload_dir)} --by {q(operator() + ' (pyinfra rollback)')}"
    arguments += " --force" if data.payload_force else ""
    token_file = "lock-token" if data.payload_lock_token else None
    if token_file:
        arguments += f" --lock-token-file {q(run_path(data, run_id) + '/' + token_file)}"
    prelude = (
        f"[ -x {HELPER} ] || {{ echo 'payload: no releases on this host (never deployed)' >&2; exit 1; }}\n"
        + staging_prelude(data, run_id, "result directory of this rollback", token_file)
    )
    return on_robot(data, "rollback", arguments, run_id, prelude)


@operations.operation(is_idempotent=False)
def switch_back(data):
    """Run `payloadctl rollback` on the robot and read its result."""
    stdin = [data.payload_lock_token] if data.payload_lock_token else None
    yield payloadctl_command(rollback_script(data, new_run_id()), stdin=stdin)


@deploy("Rollback")
def rollback_release(data):
    switch_back(name="Switch the payload back to the previous release", data=data)
