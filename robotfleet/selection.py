"""What the operator commands and the inventory files share: the exit
codes, and an inventory's hosts selected by --limit, where a pattern that
matches nothing is refused (pyinfra warns "No host matches found" and exits
0 having done nothing).  The exit codes are README's table ("Exit codes").
"""

from __future__ import annotations

import fnmatch
import os
import sys

OK = 0  # every host did what was asked
FAILED = 1  # a host failed: a step, a changed host key, a rollout's budget
REFUSED = 2  # nothing was contacted: bad fleet data, bad arguments, a --limit matching nothing
UNREACHABLE = 3  # a host could not be reached (and none failed otherwise)
CODES = {OK: "done", FAILED: "a host failed", REFUSED: "refused before contacting any host",
         UNREACHABLE: "a host was unreachable"}


class Refused(Exception):
    """One line; the command exits REFUSED."""


def unmatched(limits: list[str], names: list[str], groups: set[str]) -> list[str]:
    """The --limit patterns that match no group and no host name (as pyinfra
    matches them: a group's name, else fnmatch on host names)."""
    return [p for p in limits if p not in groups and not any(fnmatch.fnmatch(n, p) for n in names)]


def refusal(limits: list[str], inventory: str, names: list[str], groups: set[str]) -> str | None:
    missing = unmatched(limits, names, groups)
    if not missing:
        return None
    known = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
    return (f"--limit {' '.join(missing)}: no host or group of {inventory} matches "
            f"(hosts: {known or 'none'}; groups: {', '.join(sorted(groups)) or 'none'}); nothing was done")


def inventory(path: str):
    """The pyinfra inventory of ``path`` (its hosts connect through robotfleet/connect.py)."""
    from pyinfra.api import State
    from pyinfra.context import ctx_state
    from pyinfra_cli.inventory import make_inventory

    if not os.path.exists(path):
        raise Refused(f"{path}: no such inventory file")
    with ctx_state.use(State()):
        return make_inventory(path, cwd=os.getcwd())


def select(inventory_, path: str, limits: list[str]) -> list:
    """The hosts of ``inventory_`` matching any of ``limits`` (all without),
    in inventory order; Refused if a pattern matches nothing."""
    hosts = list(inventory_)
    groups = {name for name in inventory_.groups if not name.startswith("@")}
    problem = refusal(limits, path, [h.name for h in hosts], groups)
    if problem:
        raise Refused(problem)
    if not limits:
        return hosts
    return [h for h in hosts if any(fnmatch.fnmatch(h.name, p) or p in h.groups for p in limits)]


def refused(error: Refused) -> int:
    print(error, file=sys.stderr)
    return REFUSED
