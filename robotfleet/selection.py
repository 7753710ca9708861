"""What the operator commands and the inventory files share: the exit codes, and an inventory's
hosts selected by --limit, where a pattern that matches nothing is refused
(pyinfra warns "No host matches found" and exits 0 having done nothing).
The exit codes are README's table ("Exit codes").

A --limit is a comma list of terms (``--limit robot1,robot2``; the option
may also be repeated); a term is what pyinfra's own --limit takes, a group's
name or a glob on host names (``robot*``, ``robot0[1-3]``), or, as in
Ansible's patterns, ``all`` (every host), ``&TERM`` (only hosts also in
TERM), ``!TERM`` (not those) and a subscript: ``robots[0]``, ``robots[-1]``,
``robots[0:2]`` (the first three, both ends counted), ``robots[2:]``: those
of the hosts TERM matches, in inventory order, counted from 0.  pyinfra's
deploys get the same through robotfleet/inventory.py, which names each such
--limit as a group of its hosts.
"""

from __future__ import annotations

import contextlib
import fnmatch
import os
import re
import shlex
import sys

from robotfleet import CHECKOUT

OK = 0  # every host did what was asked
FAILED = 1  # a host failed: a step, a changed host key, a rollout's budget
REFUSED = 2  # nothing was contacted: bad fleet data, bad arguments, a --limit matching nothing
UNREACHABLE = 3  # a host could not be reached (and none failed otherwise)
CODES = {
    OK: "done",
    FAILED: "a host failed",
    REFUSED: "refused before contacting any host",
    UNREACHABLE: "a host was unreachable",
}


ALL = "all"  # Ansible's group of every host (pyinfra's inventories have none: robotfleet/inventory.py)
# Ansible's PATTERN_WITH_SUBSCRIPT (ansible/inventory/manager.py), less its
# [x-y], which Ansible has removed and pyinfra's globs read as characters.
SUBSCRIPT = re.compile(r"(?P<base>.+)\[(?:(?P<index>-?[0-9]+)|(?P<start>[0-9]+):(?P<end>[0-9]*))\]")


class Refused(Exception):
    """One line; the command exits REFUSED."""


def terms(limit: str) -> list[str]:
    """The terms of one --limit value: ``a,b,!c`` -> [a, b, !c]."""
    return [term.strip() for term in limit.split(",") if term.strip()]


def needs_group(limit: str) -> bool:
    """Whether pyinfra's own --limit cannot take ``limit`` as it is (a list,
    an intersection or an exclusion): robotfleet/inventory.py then names it
    as a group."""
    found = terms(limit)
    return len(found) != 1 or found[0].startswith(("!", "&")) or SUBSCRIPT.fullmatch(found[0]) is not None


def _matches(term: str, hosts: list[tuple[str, set[str]]], groups: set[str]) -> list[str]:
    """pyinfra's matching of one term: a group's name, else a glob on host
    names; Ansible's all, and its subscript of either."""
    subscript = SUBSCRIPT.fullmatch(term)
    if subscript:
        matched = _matches(subscript["base"], hosts, groups)
        return matched[_slice(subscript)] if matched else []
    if term in groups:
        return [name for name, of in hosts if term in of]
    if term == ALL:
        return [name for name, _ in hosts]
    return [name for name, _ in hosts if fnmatch.fnmatch(name, term)]


def _slice(subscript: re.Match) -> slice:
    """Ansible's _apply_subscript: [i] one host (-1 the last), [i:j] both
    ends counted, [i:] to the last."""
    if subscript["index"] is not None:
        index = int(subscript["index"])
        return slice(index, index + 1 if index != -1 else None)
    start, end = int(subscript["start"]), subscript["end"]
    return slice(start, int(end) + 1 if end else None)


def _problem(term: str) -> str | None:
    if term.startswith("~"):
        return f"{term}: regular expressions (~) are not supported; use a glob (robot*) or a group's name"
    if term[:1] in ("!", "&") and not term[1:].strip():
        return f"{term!r}: {term[0]} needs a group or host pattern after it"
    subscript = SUBSCRIPT.fullmatch(term.lstrip("!&").strip())
    if ":" in (subscript["base"] if subscript else term) and (subscript or "[" not in term):
        return f"{term}: separate patterns with commas (robots,laptops), not ':'"
    if subscript and subscript["end"] and int(subscript["end"]) < int(subscript["start"]):
        return f"{term}: a subscript [begin:end] needs begin <= end (both counted, from 0)"
    return None


def _unmatched(term: str, hosts: list[tuple[str, set[str]]], groups: set[str]) -> str:
    """Why ``term`` (it matches nothing) matches nothing, where a subscript can say more."""
    subscript = SUBSCRIPT.fullmatch(term)
    if not subscript:
        return "no host or group of {inventory} matches"
    base, shown = subscript["base"], term[len(subscript["base"]) :]
    found = _matches(base, hosts, groups)
    if found:
        return (
            f"{base} matches {len(found)} host(s), {base}[0] to {base}[{len(found) - 1}]; {shown} is Ansible's "
            "subscript of them, counted from 0"
        )
    return (
        f"{shown} is Ansible's subscript of the hosts {base} matches (counted from 0), and no host or group of "
        f"{{inventory}} matches {base}; for host names in a range write a glob ({base}[1-3], {base}*) or a comma "
        "list"
    )


def resolve(limits: list[str], hosts: list[tuple[str, set[str]]], groups: set[str]) -> tuple[list[str], list[str]]:
    """(the host names ``limits`` select, in inventory order; the terms that
    match nothing or cannot be read).  ``hosts``: (name, its groups)."""
    bad: list[str] = []
    selected: set[str] = set()
    for limit in limits:
        found = terms(limit) or [limit]
        chosen: set[str] = set()
        plain = [t for t in found if not t.startswith(("!", "&"))] or ["*"]
        for term in plain:
            matched = _matches(term, hosts, groups)
            if not matched:
                bad.append(term)
            chosen |= set(matched)
        for term in (t for t in found if t.startswith("&")):
            matched = _matches(term[1:].strip(), hosts, groups)
            if not matched:
                bad.append(term)
            chosen &= set(matched)
        for term in (t for t in found if t.startswith("!")):
            matched = _matches(term[1:].strip(), hosts, groups)
            if not matched:
                bad.append(term)
            chosen -= set(matched)
        selected |= chosen
    return [name for name, _ in hosts if name in selected], bad


def refusal(limits: list[str], inventory: str, hosts: list[tuple[str, set[str]]], groups: set[str]) -> str | None:
    """One line if a --limit cannot be read, or a term or a whole --limit
    selects no host; None when every one selects some."""
    for limit in limits:
        for term in terms(limit):
            problem = _problem(term)
            if problem:
                return f"--limit {problem}; nothing was done"
    selected, bad = resolve(limits, hosts, groups)
    names = [name for name, _ in hosts]
    known = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
    where = f"(hosts: {known or 'none'}; groups: {', '.join(sorted(groups)) or 'none'}); nothing was done"
    if bad:
        shown = [term.lstrip("!&").strip() for term in bad]
        why = _unmatched(shown[0], hosts, groups).format(inventory=inventory)
        return f"--limit {' '.join(shown)}: {why} {where}"
    if limits and not selected:
        return f"--limit {','.join(limits)}: selects no host of {inventory} {where}"
    return None


def pyinfra_inventory(path: str) -> tuple[str, dict[str, str]]:
    """What pyinfra is given for the inventory argument ``path``: (the
    inventory file, the environment it reads the fleet from).  A .py file is
    a pyinfra inventory already (its fleet: $ROBOT_FLEET, else its own); a
    fleet file (YAML, INI) or an inventory directory is read by the
    checkout's inventories/robots.py with ROBOT_FLEET naming it.  Refused
    when there is no such file or directory."""
    if not os.path.exists(path):
        raise Refused(
            f"{path}: no such inventory: give the fleet file (inventories/robots.yaml), an Ansible "
            "inventory file or directory, or a pyinfra inventory (inventories/robots.py)"
        )
    if os.path.isfile(path) and path.endswith(".py"):
        return path, {}
    # The fleet as given (relative to this directory, where pyinfra runs): its lines name it so.
    return os.path.relpath(CHECKOUT / "inventories" / "robots.py"), {"ROBOT_FLEET": path}


def pyinfra_command(path: str) -> str:
    """A pyinfra command line's start for the inventory argument ``path``:
    ``pyinfra inventories/robots.py``, or for a fleet
    ``ROBOT_FLEET=fleet.yaml pyinfra inventories/robots.py``."""
    file, env = pyinfra_inventory(path)
    return ("ROBOT_FLEET=" + shlex.quote(path) + " " if env else "") + f"pyinfra {shlex.quote(file)}"


@contextlib.contextmanager
def _environment(values: dict[str, str]):
    saved = {key: os.environ.get(key) for key in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def inventory(path: str):
    """The pyinfra inventory of the inventory argument ``path`` (any kind:
    pyinfra_inventory); its hosts connect through robotfleet/connect.py."""
    from pyinfra.api import State
    from pyinfra.context import ctx_state
    from pyinfra_cli.inventory import make_inventory

    file, env = pyinfra_inventory(path)
    with ctx_state.use(State()), _environment(env):
        try:
            return make_inventory(file, cwd=os.getcwd())
        except Exception as error:  # a .py that is no inventory (deploy.py): pyinfra's traceback otherwise
            cause = getattr(error, "exception", error)
            why = " ".join(f"{type(cause).__name__}: {cause}".split())
            raise Refused(
                f"{path}: not an inventory pyinfra can load ({why}); give the "
                "fleet file (inventories/robots.yaml), an Ansible inventory file or directory, or "
                "inventories/robots.py"
            ) from None


def select(inventory_, path: str, limits: list[str]) -> list:
    """The hosts of ``inventory_`` matching ``limits`` (all without), in
    inventory order; Refused if a pattern matches nothing."""
    hosts = list(inventory_)
    groups = {name for name in inventory_.groups if not name.startswith("@")}
    listed = [(h.name, set(h.groups)) for h in hosts]
    problem = refusal(limits, path, listed, groups)
    if problem:
        raise Refused(problem)
    if not limits:
        return hosts
    chosen = set(resolve(limits, listed, groups)[0])
    return [h for h in hosts if h.name in chosen]


def refused(error: Refused) -> int:
    print(error, file=sys.stderr)
    return REFUSED
