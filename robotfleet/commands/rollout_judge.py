"""What a push rollout waits for and how it judges a wave (pure): each
robot's target (each role's rollout part, with the rollout's --data on top of
the host's data, as the deploy will see it), and from pyinfra's JSON results,
the robots' status rows and the roles' own results of the wave's deployment,
which robots are done, failed or skipped.  Running the waves is
commands/rollout.py's."""

from __future__ import annotations

from robotfleet import deploy_roles, reasons


class _WithOverrides(dict):
    """A host's data with the rollout's --data overrides on top (what the
    deploy will see), read as pyinfra's host data is."""

    def __init__(self, data, overrides: dict):
        super().__init__({**data.dict(), **overrides} if hasattr(data, "dict") else {**data, **overrides})

    __getattr__ = dict.get


def read_overrides(pairs: list[str]) -> dict:
    """--data key=value pairs as pyinfra reads them (true/false, integers and
    JSON text become values: a mapping such as payload_image_pins arrives as
    a mapping), so the targets are what the deploy will see."""
    from pyinfra_cli.util import parse_cli_arg

    return {key: parse_cli_arg(value) for key, _, value in (pair.partition("=") for pair in pairs if "=" in pair)}


def targets_of(roles, data, overrides: dict) -> dict:
    """What the rollout waits for on a host: each role's target."""
    view = _WithOverrides(data, overrides)
    return {role.name: role.rollout.target(view) for role in roles if role.rollout}


def missing(roles, row: dict, target: dict) -> str | None:
    """None when the host's status row shows every role's target reached."""
    for role in roles:
        if role.rollout and role.name in target:
            why = role.rollout.missing(row, target[role.name])
            if why:
                return why
    return None


def not_connected(results: dict | None) -> set[str]:
    """The hosts pyinfra failed without an operation failing: it could not
    connect to them (from its JSON results)."""
    if results is None:
        return set()
    return set(results.get("failed_hosts", [])) - {h for op in results.get("operations", []) for h in op["error"]}


def reported(roles, row: dict, deployment: str | None) -> tuple[bool, str] | None:
    """The roles' own structured results of ``deployment`` on the host (its
    status row): (ok, why) of the first that failed, else of the first."""
    if not deployment:
        return None
    found = [
        r
        for r in (role.rollout.result(row, deployment) for role in roles if role.rollout and role.rollout.result)
        if r is not None
    ]
    return next((r for r in found if not r[0]), found[0] if found else None)


def judge_wave(hosts, results, rows, targets, unreachable_fails, roles=None, deployment=None):
    """(done, failed, skipped) for a wave, from structured data only (pure):
    pyinfra's JSON results (None when it printed none: every host failed,
    "No hosts remaining!"), the robots' status rows and the roles' results
    of this ``deployment`` that the rows carry."""
    roles = deploy_roles.roles() if roles is None else roles
    operations = (results or {}).get("operations", [])
    op_errors = {h: [op.get("name") or "an operation" for op in operations if h in op["error"]] for h in hosts}
    lost = not_connected(results)
    done, failed, skipped = [], {}, {}
    for host in hosts:
        row = rows.get(host) or {"reachable": False}
        why = missing(roles, row, targets[host])
        own = reported(roles, row, deployment)
        deploy_failed = results is None or bool(op_errors[host]) or host in results.get("failed_hosts", [])
        if (
            own is None and (host in lost or not row.get("reachable")) and reasons.unreachable(row.get("error") or "")
        ):  # a host key or login refused is a failure, below
            reason = "unreachable: " + (row.get("error") or "cannot connect")
            (failed if unreachable_fails else skipped)[host] = reason
        elif own is not None and not own[0]:
            failed[host] = own[1]
        elif deploy_failed or why is not None:
            steps = ", ".join(op_errors[host])
            failed[host] = why or (f"the deploy failed at: {steps}" if steps else "the deploy failed")
        else:
            done.append(host)
    return done, failed, skipped
