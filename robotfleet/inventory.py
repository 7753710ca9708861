"""What the inventory files (inventories/*.py) call: the fleet file, checked
against every setting of deploy.py's roles before pyinfra connects anywhere."""

from __future__ import annotations

import hashlib
import os
import shlex
import sys
from pathlib import Path

import click

from robotfleet import CHECKOUT, connect, deploy_roles, limits, pyinfra_patches, selection
from robotfleet.fleet.validate import Fleet, FleetError, display_path, load, parse

__all__ = [
    "Fleet",
    "FleetError",
    "display_path",
    "load_or_exit",
    "parse_or_exit",
    "pyinfra_groups",
    "refuse",
    "require_checkout",
    "require_python_inventory",
    "SOURCES",
]

# Where the fleet this process loaded came from (its file or directory):
# what a rollout's lock is per (robotfleet/commands/rollout_plan.py lock_path).
SOURCES: list[str] = []


def refuse(lines: list[str]) -> None:
    """Stop the pyinfra run before any connection: the lines, exit status 2.
    (os._exit: pyinfra would turn an exception here into a traceback.)"""
    for line in lines:
        print(line, file=sys.stderr)
    sys.stderr.flush()
    os._exit(2)


def require_checkout() -> None:
    """Under pyinfra's CLI, refuse to go on unless it runs in the checkout:
    pyinfra reads config.py and group_data/ from the directory it runs in,
    so from anywhere else it would silently drop the fleet's settings (strict
    host-key checking among them: a robot's key would be accepted on first
    use and written to ~/.ssh/known_hosts)."""
    if click.get_current_context(silent=True) is None:
        return  # robotfleet's own commands: they read the settings themselves
    if Path.cwd().resolve() != CHECKOUT:
        refuse(
            [
                f"pyinfra runs in {Path.cwd()}, not in the checkout {CHECKOUT}: its config.py and group_data/ "
                f"(strict host-key checking, sudo, every default) would not apply; run it there: "
                f"cd {CHECKOUT}, or pyinfra --chdir {CHECKOUT} ..."
            ]
        )


def require_python_inventory() -> None:
    """Under pyinfra's CLI (config.py), refuse a fleet file or an Ansible
    inventory given as pyinfra's inventory, which pyinfra would run as Python
    (a SyntaxError) or fail to read (a directory): one line with the form
    that works."""
    context = click.get_current_context(silent=True)
    given = context.params.get("inventory") if context is not None else None
    if not isinstance(given, str) or given.endswith(".py") or not os.path.exists(given):
        return
    words = list(sys.argv[1:])  # the command as typed, less the inventory
    if given in words:
        words.remove(given)
    rest = " ".join(shlex.quote(word) for word in words)
    refuse(
        [
            f"{given}: pyinfra takes a Python inventory; it reads a fleet file or an Ansible inventory through "
            f"inventories/robots.py: {selection.pyinfra_command(given)} {rest}".rstrip()
        ]
    )


def _refuse_fleet(error: FleetError) -> None:
    refuse(error.lines + error.notes + [f"{len(error.lines)} problem(s) in the fleet file; no host was contacted."])


# A fleet file's notes (Ansible's own variables ignored, an older name that
# wins) say nothing wrong: on a terminal each is told once per fleet file,
# remembered in the user's cache, so that every command does not repeat it,
# and `robotfleet inventory` always tells them (EVERY_NOTE).  Where stderr is
# not a terminal (a CI log, a pull robot's journal) a log stays whole: every
# time, and nothing written.  TOLD_ENV: a robotfleet command that has told
# them already runs pyinfra with it (a rollout's waves).
EVERY_NOTE = False
TOLD_ENV = "ROBOTFLEET_NOTES_TOLD"


def _noted(fleet: Fleet, source: str) -> Fleet:
    if fleet.notes and _to_tell(fleet.notes, source):
        for note in fleet.notes:
            print(note, file=sys.stderr)
        if not EVERY_NOTE and sys.stderr.isatty():
            print(
                f"(said once for this fleet; robotfleet inventory {shlex.quote(source)} --graph says it again)",
                file=sys.stderr,
            )
    return fleet


def _to_tell(notes: list[str], source: str) -> bool:
    if EVERY_NOTE:
        return True
    if os.environ.get(TOLD_ENV):
        return False
    if not sys.stderr.isatty():
        return True
    key = hashlib.sha256("\0".join([os.path.abspath(source), *notes]).encode()).hexdigest()
    mark = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "robotfleet" / "notes-told" / key
    if mark.exists():
        return False
    try:
        mark.parent.mkdir(parents=True, exist_ok=True)
        mark.touch()
    except OSError:  # no cache to remember it in: told each time
        pass
    return True


def load_or_exit(path: Path) -> Fleet:
    """The fleet file at ``path``, or its problems printed and exit 2."""
    SOURCES.append(os.path.abspath(path))
    try:
        return _noted(load(path, deploy_roles.registry()), str(path))
    except FleetError as error:
        _refuse_fleet(error)


def parse_or_exit(text: str | bytes, shown: str, source: str | None = None) -> Fleet:
    """Fleet YAML ``text`` (named ``shown`` in problem lines; from ``source``,
    default ``shown``), or exit 2."""
    SOURCES.append(os.path.abspath(source or shown))
    try:
        return _noted(parse(text, shown, deploy_roles.registry()), source or shown)
    except FleetError as error:
        _refuse_fleet(error)


def pyinfra_groups(fleet: Fleet, inventory: str) -> dict[str, list]:
    """The groups an inventory file hands pyinfra: robots and laptops with
    each host's data, the fleet file's other groups (Ansible's) as host
    names, so --limit takes them too, and each --limit or --exclude that
    pyinfra cannot read itself (a comma list, ``&group``, ``!host``) as a
    group of the hosts it selects (robotfleet/selection.py).  Every host
    connects through robotfleet/connect.py (``@fleet/<name>``); ``inventory``
    is the inventory file (its __file__), named in the command that enrolls
    a host key."""
    require_checkout()
    connect.names([], inventory)
    pyinfra_patches.install()  # before pyinfra makes a host of each name
    short = limits.raise_open_files(sum(len(hosts) for hosts in fleet.groups.values()))
    limits.collect_less_often()
    if short:
        print(f"robotfleet: {short}", file=sys.stderr)
    groups = {name: connect.names([(host, {}) for host in hosts]) for name, hosts in fleet.subgroups.items()}
    groups.update(_limit_groups(fleet, inventory))
    return {**groups, **{name: connect.names(hosts) for name, hosts in fleet.groups.items()}}


def _limit_groups(fleet: Fleet, inventory: str) -> dict[str, list]:
    """pyinfra's CLI only warns about a --limit or --exclude that matches no
    host, and exits 0 having done nothing: refuse it before connecting.
    The --limit and --exclude values pyinfra cannot read, as groups."""
    context = click.get_current_context(silent=True)
    if context is None:
        return {}
    hosts, groups = _membership(fleet, Path(inventory).stem)
    made = {}
    for option in ("limit", "exclude"):
        values = list(context.params.get(option) or ())
        problem = selection.refusal(values, display_path(Path(inventory)), hosts, groups)
        if problem:
            refuse([problem if option == "limit" else problem.replace("--limit", "--exclude", 1)])
        for value in values:
            if selection.terms(value) == [selection.ALL]:  # pyinfra's inventories have no group all to find
                refuse(
                    [
                        f"--{option} all: pyinfra has no group all; a deploy without --{option} is every host "
                        f"(all,!HOST leaves some out); nothing was done"
                    ]
                )
            if selection.needs_group(value):
                chosen = selection.resolve([value], hosts, groups)[0]
                made[value] = connect.names([(host, {}) for host in chosen])
    return made


def _membership(fleet: Fleet, stem: str) -> tuple[list[tuple[str, set[str]]], set[str]]:
    """(each host with its groups, every group) as pyinfra will see them: the
    kinds, the fleet's other groups and the inventory file's name (a group
    of every host unless the file has a group of that name; pyinfra has no
    group all)."""
    defined = {*(g for g, hosts in fleet.groups.items() if hosts), *fleet.subgroups}
    everyone = {stem} if stem not in defined else set()
    hosts = []
    for kind, listed in fleet.groups.items():
        for name, _ in listed:
            hosts.append((name, {kind, *everyone, *(g for g, members in fleet.subgroups.items() if name in members)}))
    return hosts, defined | everyone
