"""Asking the fleet for status: one row per host, in inventory order, each
host asked with one SSH command (its status parts, robotfleet/status_parts.py)
at most ``parallel`` at once, a pull robot read from its last report instead
(commands/pull/status.py), and whether each host is in its declared state
(drift).  What the rows look like to the operator is commands/status.py's."""

from __future__ import annotations

import gevent
from gevent.lock import Semaphore

from robotfleet import deploy_roles, reasons, selection
from robotfleet.checkers import one_line
from robotfleet.fleet import pull_mode
from robotfleet.role import GROUPS
from robotfleet.status_parts import row, sections, status_command

# Hosts asked at once by default: a handshake costs the operator a few ms of its one core, so 200 in flight
# stay far inside the connect timeout, and powered-off robots, which hold their place for it, leave room.
PARALLEL = 200


def collect(
    inventory_path: str,
    limits: list[str],
    roles=None,
    answered=None,
    remote: str | None = None,
    parallel: int = PARALLEL,
) -> list[dict]:
    """One row per host of ``inventory_path`` matching ``limits``, in
    inventory order; ``answered(row, count, total)`` is called as each host
    answers (or fails to).  Hosts with ``pull_enabled: true`` are read from their
    reports on the fleet remote (``remote``, else the checkout's origin), not
    over SSH; at most ``parallel`` at once.  Raises selection.Refused."""
    from pyinfra.api import Config, State
    from pyinfra.context import ctx_state

    roles = deploy_roles.roles() if roles is None else roles
    inventory = selection.inventory(inventory_path)
    hosts = selection.select(inventory, inventory_path, limits)
    pulled = [h for h in hosts if pull_mode.pulls(h.data)]
    found = _pull_rows(pulled, remote)
    for host in pulled:
        if found[host.name]["reachable"]:
            found[host.name]["drift"] = drift(roles, found[host.name], host.data)
        _about(host, found[host.name])
    state = State(inventory=inventory, config=Config(CONNECT_TIMEOUT=10, PARALLEL=parallel), check_for_changes=False)
    state.limit_hosts = [h for h in hosts if h not in pulled]
    slots = Semaphore(parallel)

    def one(host):
        with slots:
            return _one(host, roles)

    with ctx_state.use(state):
        jobs = {gevent.spawn(one, host): host for host in hosts if host not in pulled}
        for count, job in enumerate(gevent.iwait(list(jobs)), 1):
            if answered is not None:
                answered(_value(job, jobs[job], roles), count, len(jobs))
        job_of = {id(host): job for job, host in jobs.items()}
        return [found[host.name] if host in pulled else _value(job_of[id(host)], host, roles) for host in hosts]


def _pull_rows(hosts, remote: str | None) -> dict[str, dict]:
    if not hosts:
        return {}
    from robotfleet.commands.pull import status as pullstatus

    try:
        pulled = [(h.name, h.data) for h in hosts]
        return pullstatus.rows(pulled, pullstatus.remote_of(remote, pulled))
    except pullstatus.ReportsUnavailable as error:
        return {
            h.name: {
                "host": h.name,
                "reachable": False,
                "via": "report",
                "pull": "reports unreadable",
                "stale": True,
                "error": str(error),
            }
            for h in hosts
        }


def _value(job, host, roles) -> dict:
    if job.successful():
        return job.value
    return row(host.name, roles, None, f"status failed: {one_line(str(job.exception))[:200]}")


def _one(host, roles) -> dict:
    from pyinfra.api.command import StringCommand
    from pyinfra.api.exceptions import ConnectError

    try:
        host.connect(raise_exceptions=True, show_errors=False)
    except ConnectError as error:
        return _about(host, row(host.name, roles, None, error.args[0]))
    ok, output = host.run_shell_command(StringCommand(status_command(roles, host.data)), _sudo=True)
    if not ok:
        said = output.stderr.strip()
        last = said.splitlines()[-1] if said else ""
        if reasons.short_reason(last):  # the connection ended under the command (robotfleet/connect.py)
            return _about(host, row(host.name, roles, None, last))
        return _about(host, {**row(host.name, roles, {}), "error": said[-200:]})
    found = row(host.name, roles, sections(output.stdout))
    found["drift"] = drift(roles, found, host.data)
    return _about(host, found)


def _about(host, found: dict) -> dict:
    found["kind"] = next((group for group in GROUPS if group in host.groups), None)
    return found


class _View(dict):
    """A host's data as the roles' rollout parts read it (attributes)."""

    __getattr__ = dict.get


def drift(roles, found: dict, data) -> str | None:
    """Why the host is not in its declared state, where status can tell
    (each role's rollout part, as a rollout judges it), else None."""
    view = _View(data.dict() if hasattr(data, "dict") else data)
    for role in roles:
        if role.rollout:
            why = role.rollout.missing(found, role.rollout.target(view))
            if why:
                return why
    return None
