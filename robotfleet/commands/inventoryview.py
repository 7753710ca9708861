"""The fleet as robotfleet reads it, and where each value comes from: like ansible-inventory.

    robotfleet inventory INVENTORY --graph [GROUP]          the groups and their hosts, as a tree
    robotfleet inventory INVENTORY --list                   every group and each host's settings, as JSON
    robotfleet inventory INVENTORY --host robot1 [--defaults]

--host shows each setting the fleet gives the host, its value and the file,
line and group or host that set it, then the values it overrides (lowest
last); --defaults adds every other setting at its default.  Secrets (URL
passwords, values whose key names a token, secret, password, key or
credential, the registry passwords the roles know of: robotfleet/secrets.py)
are masked.  Where sibling groups (of one depth) set a setting differently,
Ansible's rule picks one silently; a note says which won and why (as every
command that reads the fleet does).  Nothing is contacted.  INVENTORY is the
fleet file, an Ansible inventory file or directory, or a pyinfra inventory
(the fleet it reads: $ROBOT_FLEET, else the .yaml beside it).
Exit status: 0, or 2 (bad fleet data, no such host or group).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from robotfleet import commands, deploy_roles, inventory, secrets, selection
from robotfleet.checkers import did_you_mean, one_line
from robotfleet.fleet import provenance, tree
from robotfleet.fleet.connection import OLDER_NAMES
from robotfleet.fleet.tree import PRIORITY_KEY
from robotfleet.pull.operator.publishing import HostData


def fleet_of(given: str) -> Path:
    """The fleet an inventory argument names: itself, or the one a pyinfra
    inventory reads ($ROBOT_FLEET, else the .yaml beside it, as inventories/robots.py)."""
    _, env = selection.pyinfra_inventory(given)
    return Path(env.get("ROBOT_FLEET") or os.environ.get("ROBOT_FLEET") or Path(given).with_suffix(".yaml"))


def written(registry):
    """What a layer sets, under the settings' own names: setting -> (the key as written, its value).
    Ansible's older ansible_ssh_* names win over the newer ones wherever they
    are set (host_lines), in one place too."""

    def of(layer: tree.Layer) -> dict:
        found = {}
        for key, value in layer.values.items():
            if (
                not isinstance(key, str)
                or key == PRIORITY_KEY
                or (key.startswith("ansible_") and key not in registry.aliases)
            ):
                continue
            setting = OLDER_NAMES.get(key) or registry.name_of(key)
            if found.get(setting, ("",))[0] not in OLDER_NAMES:
                found[setting] = (key, value)
        return found

    return of


def kind_and_data(fleet, host: str) -> tuple[str, dict] | None:
    for kind, hosts in fleet.groups.items():
        for name, data in hosts:
            if name == host:
                return kind, data
    return None


def held(registry, kind: str, data: dict) -> set[str]:
    """The secrets the host's data holds, and the registry passwords the roles find for it."""
    merged = HostData({**registry.defaults(kind), **data})
    found = secrets.held_in(data)
    for role in deploy_roles.roles():
        if role.secrets:
            found.update(s for s in role.secrets(merged) if s)
    return found


def shown(value, masked: set[str]) -> str:
    text = value if isinstance(value, str) else json.dumps(value, sort_keys=True)
    return one_line(secrets.mask(text, masked))


def host_lines(fleet, host: str, registry, defaults: bool) -> list[str]:
    kind, data = kind_and_data(fleet, host)
    groups = sorted(fleet.tree.above(host) - {tree.ALL})
    masked = held(registry, kind, data)
    rows = []
    for name, found in sorted(provenance.origins(fleet.tree, host, written(registry)).items()):
        older = [o for o in found if o.value[0] in OLDER_NAMES]
        winner = (older or found)[-1]
        value = data.get(name, winner.value[1])
        combined = " (combined with the values below)" if name in dict(registry.mergers) else ""
        rows.append((name, shown(value, masked), origin(winner, name) + combined))
        rows += [
            ("", "  over " + shown(o.value[1], masked), origin(o, name)) for o in reversed(found) if o is not winner
        ]
    if defaults:
        rows += [
            (name, shown(value, masked), f"default ({kind})")
            for name, value in sorted(registry.defaults(kind).items())
            if name not in data
        ]
    width = max(len(r[0]) for r in rows + [("SETTING", "", "")])
    values = min(48, max(len(r[1]) for r in rows + [("", "VALUE", "")]))
    return [f"{host}: a {kind[:-1]}, in {', '.join(groups)}", f"{'SETTING':{width}}  {'VALUE':{values}}  FROM"] + [
        f"{n:{width}}  {v:{values}}  {f}" for n, v, f in rows
    ]


def origin(found: provenance.Origin, setting: str) -> str:
    """``group robots (file:line)``, with the key as written where it is not the setting's name."""
    key = found.value[0]
    return found.who + (f" as {key}" if key != setting else "") + f" ({found.at})"


def children(groups: tree.Tree, name: str) -> list[str]:
    """The groups right under ``name``, in the order the inventory declares
    them, as Ansible has them: all's are those under no other group, with
    Ansible's ungrouped first."""
    if name != tree.ALL:
        return [g for g, group in groups.groups.items() if name in group.parents]
    top = [g for g, group in groups.groups.items() if g not in (tree.ALL, tree.UNGROUPED) and group.parents <= {name}]
    return [tree.UNGROUPED, *top]


def members(groups: tree.Tree, name: str) -> list[str]:
    """The hosts listed in group ``name`` itself, in the order listed (in
    ungrouped: those listed in no other group, as Ansible has it)."""
    if name == tree.UNGROUPED:
        return [host for host, listed in groups.hosts.items() if {g for g, _ in listed} <= {tree.ALL, tree.UNGROUPED}]
    return list(groups.groups[name].members) if name in groups.groups else []


def graph(groups: tree.Tree, name: str, depth: int = 0) -> list[str]:
    """ansible-inventory --graph's tree from group ``name``."""
    lines = [("  |" * depth + "--" if depth else "") + f"@{name}:"]
    for child in children(groups, name):
        lines += graph(groups, child, depth + 1)
    if name != tree.ALL:
        lines += ["  |" * (depth + 1) + f"--{host}" for host in members(groups, name)]
    return lines


def listing(fleet, registry) -> str:
    """ansible-inventory --list's JSON: each group's hosts and children, each host's settings (masked)."""
    groups = fleet.tree
    out: dict = {"_meta": {"hostvars": {}}, tree.ALL: {"children": children(groups, tree.ALL)}}
    masked: set[str] = set()
    for kind, hosts in fleet.groups.items():
        for name, data in hosts:
            out["_meta"]["hostvars"][name] = data
            masked |= held(registry, kind, data)
    for name in [g for g in groups.groups if g not in (tree.ALL, tree.UNGROUPED)] + [tree.UNGROUPED]:
        entry = {"hosts": members(groups, name), "children": children(groups, name)}
        out[name] = {key: value for key, value in entry.items() if value}
    return secrets.mask(json.dumps(out, indent=2, sort_keys=True), masked)


def build_parser() -> argparse.ArgumentParser:
    """``robotfleet inventoryview``'s command line (the shell completion and the manual page read it too)."""
    parser = commands.parser("inventory", __doc__)
    commands.add_inventory(parser)
    shown_as = parser.add_mutually_exclusive_group(required=True)
    shown_as.add_argument("--graph", nargs="?", const=tree.ALL, metavar="GROUP", help="the groups as a tree")
    shown_as.add_argument("--list", action="store_true", help="every group and host's settings, as JSON")
    shown_as.add_argument("--host", metavar="NAME", help="one host's settings and where each comes from")
    parser.add_argument("--defaults", action="store_true", help="with --host: every other setting at its default")
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.inventory = commands.inventory_of(parser, args)
    try:
        path = fleet_of(args.inventory)
    except selection.Refused as error:
        return selection.refused(error)
    registry = deploy_roles.registry()
    inventory.EVERY_NOTE = True  # the command that shows the fleet tells its notes each time
    fleet = inventory.load_or_exit(path)  # its problems and notes printed, exit 2
    if args.host is not None:
        if kind_and_data(fleet, args.host) is None:
            known = [name for hosts in fleet.groups.values() for name, _ in hosts]
            return selection.refused(
                selection.Refused(
                    f"inventory: no host {args.host!r} in {inventory.display_path(path)}"
                    + did_you_mean(args.host, known)
                )
            )
        print("\n".join(host_lines(fleet, args.host, registry, args.defaults)))
    elif args.list:
        print(listing(fleet, registry))
    else:
        if args.graph not in {*fleet.tree.groups, tree.UNGROUPED}:
            return selection.refused(
                selection.Refused(
                    f"inventory: --graph {args.graph}: no group of that name in {inventory.display_path(path)}"
                    + did_you_mean(args.graph, sorted(fleet.tree.groups))
                )
            )
        print("\n".join(graph(fleet.tree, args.graph)))
    return selection.OK
