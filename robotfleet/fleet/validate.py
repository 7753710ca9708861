"""The fleet file: load it, check every host's data, hand pyinfra its groups.

The fleet is an Ansible inventory: a YAML or INI file, or a directory of
them, with group_vars/ and host_vars/ beside it (robotfleet/fleet/sources.py;
its groups: robotfleet/fleet/tree.py, INI: robotfleet/fleet/ini.py).  The
``robots`` and ``laptops`` groups say which hosts are which.  A host's data
is the settings' defaults < its layers in Ansible's order (tree.Tree.layers).
Ansible's connection variables are read as ours (ansible_host as address,
ansible_user as ssh_user, ...; where an older ansible_ssh_* name and the
newer one are both set, the older wins, as in Ansible); Ansible's other
variables (ansible_become, ...) configure Ansible itself and are ignored
with a note, so an Ansible inventory works as it is.
Everything is checked before pyinfra connects anywhere; each problem is one
line ``FILE[:LINE]: HOST.FIELD: message``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from robotfleet import checkers as c
from robotfleet import secrets
from robotfleet.fleet import loader, provenance, sources, tree
from robotfleet.fleet.connection import OLDER_NAMES
from robotfleet.fleet.registry import Registry, setting_of
from robotfleet.fleet.sources import MAX_BYTES, display_path
from robotfleet.fleet.tree import EXTENSION_PREFIX, HOST_NAME, PRIORITY_KEY
from robotfleet.role import GROUPS

__all__ = ["EXTENSION_PREFIX", "HOST_NAME", "Fleet", "FleetError", "check", "display_path", "load", "parse"]
ANSIBLE_PREFIX = "ansible_"
INI_BOOLEAN = "; INI reads it as text, as Ansible does: write True or False"


class FleetError(Exception):
    """The fleet's problems (``lines``), and what reading it had to note
    (``notes``: a vars file not read often explains a problem)."""

    def __init__(self, lines: list[str], notes: list[str] | None = None):
        super().__init__("\n".join(lines))
        self.lines = lines
        self.notes = notes or []


@dataclass
class Fleet:
    groups: dict[str, list[tuple[str, dict]]] = field(default_factory=dict)  # robots, laptops
    # Every other group of the file (Ansible's), as host names, for --limit.
    subgroups: dict[str, list[str]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    tree: tree.Tree | None = None  # the groups and layers it was read from (where each value comes from)

    def hosts(self, group: str) -> list[tuple[str, dict]]:
        return self.groups.get(group, [])


def load(path: Path, registry: Registry) -> Fleet:
    """Read and check the fleet at ``path`` (an inventory file or directory,
    and the group_vars/ and host_vars/ beside it); FleetError lists every problem."""
    reading = sources.Reading()
    reading.inventory(path)
    return check_tree(reading.tree, display_path(path), registry, reading.lines, reading.notes)


def parse(text: str | bytes, shown: str, registry: Registry) -> Fleet:
    """Check fleet YAML ``text``, named ``shown`` in problem lines."""
    if len(text) > MAX_BYTES:
        raise FleetError([f"{shown}: larger than {MAX_BYTES // 2**20} MiB; a fleet file is text people edit"])
    try:
        raw = loader.load(text)
    except loader.YamlProblem as problem:
        raise FleetError([c.one_line(f"{shown}: {problem}")]) from None
    return check(raw, shown, registry)


def check(raw, shown: str, registry: Registry) -> Fleet:
    """Check a loaded YAML inventory ``raw``."""
    lines: list[str] = []
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise FleetError(
            [c.one_line(f"{shown}: expected a mapping with all/robots/laptops at the top, got {c.describe(raw)}")]
        )
    return check_tree(tree.read(raw, lines, shown), shown, registry, lines, [])


def check_tree(groups: tree.Tree, shown: str, registry: Registry, lines: list[str], notes: list[str]) -> Fleet:
    """Check every host of ``groups``; ``lines`` are the problems found
    reading it, ``notes`` what reading it has to say."""
    ignored: set[str] = set()

    def report(layer: tree.Layer | None, where: str, problems, placed: dict | None = None):
        """Each problem as a line at ``layer``'s file (and the key's line), or
        with ``placed`` (a host's rules) where the host's value is written."""
        for sub, message in problems:
            location = f"{where}.{sub}" if sub and not sub.startswith("[") else f"{where}{sub}"
            key = setting_of(sub) if sub else None
            if placed is not None:
                layer, key = placed.get(key, (layer, key))
            if (
                layer is not None
                and layer.lines
                and isinstance(layer.values.get(key), str)
                and message.startswith("expected true or false")
            ):
                message += INI_BOOLEAN
            at = layer.at(key) if layer is not None else shown
            lines.append(f"{at}: {location.strip('.')}: {message}")

    def checked(where: str, layer: tree.Layer) -> tuple[dict, set[str]]:
        """A layer's settings under their own names (aliases, Ansible's names
        and the settings' old names resolved, each old name with a note; the
        older ansible_ssh_* names kept apart until the host's layers are
        merged), and the settings it has problems with."""
        own = {}
        for key, value in layer.values.items():
            if key == PRIORITY_KEY:
                if isinstance(value, bool) or not isinstance(value, int):
                    report(layer, where, [(key, f"expected a whole number, got {c.describe(value)}")])
            elif isinstance(key, str) and key.startswith(ANSIBLE_PREFIX) and key not in registry.aliases:
                ignored.add(key)
            elif isinstance(value, loader.Vaulted):
                report(
                    layer,
                    where,
                    [
                        (
                            c.key_name(key),
                            "an ansible-vault value (!vault), which robotfleet does not "
                            "decrypt: write the value, or keep it in a secret store",
                        )
                    ],
                )
            else:
                own[key] = value
        problems = registry.check_layer(own)
        report(layer, where, problems)
        refused = {registry.name_of(setting_of(sub)) for sub, _ in problems}
        named: dict = {}
        for key, value in own.items():
            name = key if key in OLDER_NAMES else registry.name_of(key) if isinstance(key, str) else key
            rename = registry.renamed.get(key) if isinstance(key, str) else None
            if rename is not None and rename.new in own:
                report(layer, where, [(key, f"{key} is the old name of {rename.new}, set here too; keep {rename.new}")])
                refused.add(name)
                continue
            if rename is not None:
                notes.append(
                    f"{layer.at(key)}: note: {where}: {key} is now {name}; the old name still works (rename it)"
                )
                value = registry.renamed_value(rename, value)
            if name in named:
                report(layer, where, [(c.key_name(key), f"sets {name} a second time in the same place; keep one")])
                refused.add(name)
            named[name] = value
        return named, refused

    for name in groups.circles():
        lines.append(f"{shown}: {name}: the group is its own ancestor (its children: groups form a circle)")
    # Every group's layers are checked once, whether or not a host is in it.
    verdicts: dict[int, tuple[dict, set[str]]] = {}
    for name, group in groups.groups.items():
        for layer in group.layers:
            verdicts[id(layer)] = checked(f"{name}.vars", layer)
    for name, group in groups.groups.items():
        for layer in group.files:
            verdicts[id(layer)] = checked(name, layer)
    fleet = Fleet(groups={group: [] for group in GROUPS}, tree=groups)
    combining = {name for name, _ in registry.mergers}  # settings whose layers combine: no sibling disagrees
    disagreeing: dict[provenance.Disagreement, list[str]] = {}  # each disagreement -> the hosts it concerns
    defaults: dict[str, dict] = {}  # per kind of host, made when a host of that kind is checked
    for name, listed in groups.hosts.items():
        home = listed[0][1]
        above = groups.above(name)
        kinds = [group for group in GROUPS if group in above]
        if len(kinds) > 1:
            lines.append(f"{home.at(None)}: {name}: declared in both {' and '.join(kinds)}")
            continue
        if not kinds:
            where = sorted(above - {tree.ALL}) or [tree.ALL]
            lines.append(
                f"{home.at(None)}: {name}: in neither a robots nor a laptops group "
                f"(groups: {', '.join(where)})" + c.did_you_mean(where[-1], GROUPS)
            )
            continue
        layers, refused = [], set()
        for layer in groups.layers(name):
            if id(layer) not in verdicts:  # the host's own
                verdicts[id(layer)] = checked(name, layer)
            values, bad = verdicts[id(layer)]
            layers.append(values)
            # A refused value a later layer replaces (all.vars' under a host's
            # own) is not the host's: the rules look at the one it gets.
            refused -= values.keys() - combining
            refused |= bad
        data = registry.merge(layers)
        for found in provenance.disagreements(groups, name, lambda layer: verdicts[id(layer)][0], combining):
            disagreeing.setdefault(found, []).append(name)
        resolve_older_names(data, layers, refused, name, home, notes)
        if "ssh_hostname" in refused:
            refused.add("address")
        if kinds[0] not in defaults:
            defaults[kinds[0]] = registry.defaults(kinds[0])
        merged = {**defaults[kinds[0]], **data}
        found = registry.check_host(merged, refused)
        if found:
            report(home, name, found, placements(groups.layers(name), registry))
        fleet.groups[kinds[0]].append((name, data))
        for group in above - {tree.ALL, *GROUPS}:
            fleet.subgroups.setdefault(group, []).append(name)
    notes.extend(sibling_note(found, hosts) for found, hosts in disagreeing.items())
    if ignored:
        notes.append(f"{shown}: note: {', '.join(sorted(ignored))}: Ansible's own, ignored here")
    fleet.notes = notes
    if not lines and not any(fleet.groups.values()):
        lines.append(
            f"{shown}: no hosts: declare them under robots.hosts or laptops.hosts ([robots] or [laptops] "
            "in an INI inventory)"
        )
    if lines:
        # a refused value is quoted in its line: never a secret it holds (robotfleet/secrets.py)
        held = set().union(*(secrets.held_in(layer.values) for layer in every_layer(groups)))
        raise FleetError([secrets.mask(c.one_line(line), held) for line in lines], notes)
    return fleet


def every_layer(groups: tree.Tree) -> list[tree.Layer]:
    """Every place of the tree that sets values: the groups' and the hosts'."""
    return [
        *(layer for group in groups.groups.values() for layer in [*group.layers, *group.files]),
        *(layer for listed in groups.hosts.values() for _, layer in listed),
        *(layer for layers in groups.host_files.values() for layer in layers),
    ]


def placements(layers: list[tree.Layer], registry: Registry) -> dict[str, tuple[tree.Layer, str]]:
    """Each setting of a host -> (the layer that gives the host its value,
    the key as written there): where a rule's problem with it is shown (an
    INI group's line, a group_vars/ file), not where the host is listed."""
    placed = {}
    for layer in layers:
        for key in layer.values:
            if isinstance(key, str):
                placed[OLDER_NAMES.get(key) or registry.name_of(key)] = (layer, key)
    return placed


def resolve_older_names(
    data: dict, layers: list[dict], refused: set[str], host: str, home: tree.Layer, notes: list[str]
) -> None:
    """Ansible's older connection names (ansible_ssh_host, ...) win over the
    newer ones wherever each is set, as in Ansible; a note says so where the
    newer name was set in a later layer and differs."""
    for older, setting in OLDER_NAMES.items():
        if older not in data:
            continue
        value = data.pop(older)
        if older in refused:
            refused.add(setting)
        last_older = max(i for i, layer in enumerate(layers) if older in layer)
        later = [layer[setting] for layer in layers[last_older:] if setting in layer]
        if later and later[-1] != value:
            notes.append(
                f"{home.at(None)}: note: {host}: {older} ({c.describe(value)}) wins over "
                f"{setting} ({c.describe(later[-1])}), as in Ansible"
            )
        data[setting] = value


def sibling_note(found: provenance.Disagreement, hosts: list[str]) -> str:
    """One note for a setting sibling groups disagree on, for every host concerned."""
    shown = ", ".join(hosts[:3]) + (f" and {len(hosts) - 3} more" if len(hosts) > 3 else "")
    return (
        f"{found.at}: note: {shown}: {found.setting} is group {found.winner}'s, not {', '.join(found.losers)}'s "
        f"(sibling groups that set it differently; {found.why}, as in Ansible); set it on the host or give one "
        "group a higher ansible_group_priority"
    )
