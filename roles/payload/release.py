"""A release on the robot: the spec the deploy hands payloadctl, whether a
release is needed, and the commands that run payloadctl on the robot (as a
transient systemd unit, so a dropped SSH link cannot leave it half-switched)."""

from __future__ import annotations

import datetime
import getpass
import json
import secrets
import shlex
import socket

from pyinfra import host, logger
from pyinfra.api import deploy

from robotfleet.host import operations
from robotfleet.host.snapshot import Snapshot
import roles.payload.compose as compose
import roles.payload.project as project
from roles.payload.payloadctl import lock
from roles.payload.payloadctl.spec import SETTLED, Spec
from roles.payload.robot import HELPER


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
        lock_file=data.payload_lock_file,
        checks=[check for check in checks if check],  # run in each container once healthy
        takeover=project.takeover_of(data),
    )


def operator() -> str:
    return f"{getpass.getuser()}@{socket.gethostname()}"


def request(data, doc: dict, checks: list) -> str:
    """What `payloadctl apply` reads: the spec and who asks."""
    run = {"by": f"{operator()} (pyinfra)", "force": bool(data.payload_force), "host": host.name}
    return json.dumps({"spec": spec(data, doc, checks).to_dict(), "run": run}, sort_keys=True)


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


@operations.operation()
def release(data, document: dict, checks: list, needed: bool, restart: bool):
    """Apply the release on the robot when it is not what runs there."""
    if not needed:
        host.noop("payload release is current")
        return
    run_id = new_run_id()
    yield operations.shell(apply_script(data, restart, run_id), stdin=request(data, document, checks).splitlines())


def rollback_script(data, run_id: str) -> str:
    """The previous release comes back with its own spec (payloadctl reads
    it from the release); only who asks and the override are this run's."""
    q = shlex.quote
    arguments = f"--dir {q(data.payload_dir)} --by {q(operator() + ' (pyinfra rollback)')}"
    arguments += " --force" if data.payload_force else ""
    prelude = (
        f"[ -x {HELPER} ] || {{ echo 'payload: no releases on this host (never deployed)' >&2; exit 1; }}\n"
        + staging_prelude(data, run_id, "result directory of this rollback")
    )
    return on_robot(data, "rollback", arguments, run_id, prelude)


@deploy("Rollback")
def rollback_release(data):
    operations.run(name="Switch the payload back to the previous release", script=rollback_script(data, new_run_id()))
