"""The fleet file's groups, read the way Ansible reads a YAML inventory.

    all:
      vars: {...}
      children:
        robots:
          vars: {...}
          hosts: {robot1: {...}}
          children:
            warehouse_a: {vars: {...}, hosts: {robot7: {...}}}
        laptops: {hosts: {...}}

A group has ``vars``, ``hosts`` and ``children`` (groups, nested to any
depth); top-level keys other than ``all`` are groups under ``all`` (as in
Ansible), and ``x-...`` keys are ignored (YAML anchors).  A group may be
named in several places (its definitions add up) and a host may be listed in
several groups.  A host's settings merge as Ansible merges them: ``all``,
then the groups above it, shallower before deeper and by name at the same
depth, then the host's own (in the order the file lists them).

Host names are Ansible's host patterns (robotfleet/fleet/hostpattern.py):
``robot[01:03]`` is three hosts, ``robot1:2222`` sets its port.

Which hosts are robots and which are laptops stays explicit: a host is a
robot if a group named ``robots`` is above it (at any depth), a laptop if
``laptops`` is; both is refused, neither too.

Each layer of settings keeps where it was written (``Layer``): the file,
and for an INI inventory the line of each key, so that every problem names
them.  Groups and hosts also take layers from ``group_vars/`` and
``host_vars/`` files (robotfleet/fleet/sources.py), which Ansible ranks
above the inventory's own: see ``Tree.layers``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from robotfleet import checkers as c
from robotfleet.fleet.hostpattern import PatternProblem, expand

EXTENSION_PREFIX = "x-"
UNGROUPED = "ungrouped"  # Ansible's group of hosts listed in no other group
HOST_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,62}")
GROUP_KEYS = ("vars", "hosts", "children")
ALL = "all"


PORT_KEY = "ansible_port"  # where a host pattern's :port goes, as in Ansible
PRIORITY_KEY = "ansible_group_priority"  # orders sibling groups of one depth, as in Ansible


@dataclass
class Layer:
    """Settings as written in one place: ``file`` (as shown), the line of
    each key where the format has lines (INI), and the line of the place;
    for YAML, ``places``: each key's line, shown where a value comes from
    (inventory --host), while problem lines name the YAML file alone."""

    values: dict
    file: str
    lines: dict = field(default_factory=dict)
    line: int | None = None
    places: dict = field(default_factory=dict)

    def at(self, key) -> str:
        """``file`` or ``file:line`` for ``key`` (or for the place)."""
        line = self.lines.get(key, self.line) if isinstance(key, str) else self.line
        return f"{self.file}:{line}" if line else self.file

    def source(self, key) -> str:
        """``file:line`` where ``key`` (as written) is, in either format; else as ``at``."""
        line = self.places.get(key) if isinstance(key, str) else None
        return f"{self.file}:{line}" if line else self.at(key)


@dataclass
class Group:
    name: str
    layers: list[Layer] = field(default_factory=list)  # its vars in the inventory, one per definition
    files: list[Layer] = field(default_factory=list)  # group_vars/<name>..., in Ansible's order
    parents: set[str] = field(default_factory=set)
    members: dict[str, None] = field(default_factory=dict)  # the hosts listed in it, in the order listed


@dataclass
class Tree:
    groups: dict[str, Group] = field(default_factory=dict)
    # host -> (group, its vars there) for each place it is listed, in file order
    hosts: dict[str, list[tuple[str, Layer]]] = field(default_factory=dict)
    host_files: dict[str, list[Layer]] = field(default_factory=dict)  # host_vars/<name>...
    _depths: dict[str, int] = field(default_factory=dict)

    def __post_init__(self):
        self.groups.setdefault(ALL, Group(ALL))

    def layers(self, host: str) -> list[Layer]:
        """``host``'s layers, lowest first, in Ansible's order: the inventory's
        group vars (all, then the groups by depth and name), group_vars/ files
        in the same order, the inventory's host vars, host_vars/ files."""
        return [layer for _, _, layer in self.sourced(host)]

    def sourced(self, host: str) -> list[tuple[str, str, Layer]]:
        """``host``'s layers as ``layers`` orders them, each with whose it is:
        ("group", its name) or ("host", ``host``)."""
        groups = self.ordered(self.above(host))
        return (
            [("group", g, layer) for g in groups for layer in self.groups[g].layers]
            + [("group", g, layer) for g in groups for layer in self.groups[g].files]
            + [("host", host, layer) for _, layer in self.hosts[host]]
            + [("host", host, layer) for layer in self.host_files.get(host, [])]
        )

    def listed(self, host: str, group: str, layer: Layer, port: int | None = None) -> None:
        """``host`` listed in ``group`` with ``layer``; a host pattern's port
        counts where the host is first listed only, as in Ansible."""
        self.groups.setdefault(group, Group(group)).members[host] = None
        if port is not None and host not in self.hosts:
            self.hosts[host] = [(group, Layer({PORT_KEY: port}, layer.file, line=layer.line))]
        self.hosts.setdefault(host, []).append((group, layer))

    def above(self, host: str) -> set[str]:
        """Every group ``host`` is in: where it is listed and their ancestors
        (ungrouped only if no other group lists it, as Ansible has it)."""
        found: set[str] = set()
        todo = [group for group, _ in self.hosts[host]]
        if set(todo) - {ALL, UNGROUPED}:
            todo = [group for group in todo if group != UNGROUPED]
        while todo:
            name = todo.pop()
            if name not in found:
                found.add(name)
                todo.extend(self.groups[name].parents)
        return found

    def depth(self, name: str, seen: frozenset = frozenset()) -> int:
        """The longest way down from all (Ansible's group depth)."""
        if name not in self._depths:
            parents = self.groups[name].parents - seen
            self._depths[name] = 1 + max((self.depth(p, seen | {name}) for p in parents), default=-1)
        return self._depths[name]

    def priority(self, name: str) -> int:
        """The group's ansible_group_priority (Ansible reads it from the
        inventory only, not from group_vars/; default 1)."""
        found = 1
        for layer in self.groups[name].layers:
            value = layer.values.get(PRIORITY_KEY)
            if isinstance(value, int) and not isinstance(value, bool):
                found = value
        return found

    def ordered(self, names: set[str]) -> list[str]:
        """Ansible's order of group vars: all first, then by depth, by
        ansible_group_priority, by name."""
        return sorted(names, key=lambda name: (name != ALL, self.depth(name), self.priority(name), name))

    def circles(self) -> list[str]:
        """Groups that are their own ancestors (children: definitions that
        loop, possibly across files)."""
        looped = []
        for name in self.groups:
            seen, todo = set(), list(self.groups[name].parents)
            while todo:
                parent = todo.pop()
                if parent == name:
                    looped.append(name)
                    break
                if parent not in seen:
                    seen.add(parent)
                    todo.extend(self.groups[parent].parents)
        return looped


def read(raw: dict, lines: list[str], shown: str, tree: Tree | None = None, places: dict | None = None) -> Tree:
    """The tree of ``raw`` (a loaded YAML inventory), added to ``tree`` if
    given; problems appended to ``lines``; ``places``: its keys' lines
    (robotfleet/fleet/loader.py ``load``)."""
    tree = Tree() if tree is None else tree
    places = places or {}

    def problem(where: str, message: str):
        lines.append(f"{shown}: {where}: {message}" if where else f"{shown}: {message}")

    def walk(name: str, node, parent: str | None, path: tuple[str, ...]):
        group = tree.groups.setdefault(name, Group(name))
        if parent is not None:
            group.parents.add(parent)
        if node is None:
            return
        if not isinstance(node, dict):
            problem(name, f"expected a group (a mapping with vars, hosts, children), got {c.describe(node)}")
            return
        for key in node:
            if key not in GROUP_KEYS:
                problem(
                    f"{name}.{c.key_name(key)}",
                    "unknown key" + c.did_you_mean(str(key), GROUP_KEYS) + "; a group has vars, hosts and children",
                )
        variables = node.get("vars")
        if isinstance(variables, dict):
            group.layers.append(Layer(variables, shown, places=places.get(id(variables), {})))
        elif variables is not None:
            problem(f"{name}.vars", f"expected a mapping of settings, got {c.describe(variables)}")
        hosts = node.get("hosts")
        if isinstance(hosts, dict):
            for pattern, host_vars in hosts.items():
                named = host_names(pattern, problem)
                if not named:
                    continue
                if host_vars is None:
                    host_vars = {}
                if not isinstance(host_vars, dict):
                    problem(c.key_name(pattern), f"expected a mapping of settings, got {c.describe(host_vars)}")
                    continue
                for host, port in named:
                    tree.listed(host, name, Layer(host_vars, shown, places=places.get(id(host_vars), {})), port)
        elif hosts is not None:
            problem(f"{name}.hosts", f"expected a mapping of host name to settings, got {c.describe(hosts)}")
        children = node.get("children")
        if isinstance(children, dict):
            for child, child_node in children.items():
                if group_name_problem(child, f"{name}.children", problem):
                    continue
                if child in path or child == ALL:
                    problem(f"{name}.children.{child}", "a group cannot be its own child (the groups form a circle)")
                    continue
                walk(child, child_node, name, path + (child,))
        elif children is not None:
            problem(f"{name}.children", f"expected a mapping of group name to group, got {c.describe(children)}")

    for key, node in raw.items():
        if isinstance(key, str) and key.startswith(EXTENSION_PREFIX):
            continue
        if group_name_problem(key, "", problem):
            continue
        walk(key, node, None if key == ALL else ALL, (key,))
    return tree


def host_names(pattern, problem) -> list[tuple[str, int | None]]:
    """(name, port) of each host a host pattern makes; [] after a problem."""
    if not isinstance(pattern, str):
        problem(c.key_name(pattern), f"a host name must be a string, got {c.describe(pattern)}; quote it")
        return []
    try:
        names, port = expand(pattern)
    except PatternProblem as error:
        problem(c.key_name(pattern), str(error))
        return []
    bad = [name for name in names if not HOST_NAME.fullmatch(name)]
    if bad:
        problem(
            c.key_name(pattern),
            "invalid host name (letters, digits, . _ -)"
            if bad == [pattern]
            else f"invalid host name {bad[0]!r} (letters, digits, . _ -)",
        )
        return []
    return [(name, port) for name in names]


def group_name_problem(name, where: str, problem) -> bool:
    if isinstance(name, str) and HOST_NAME.fullmatch(name):
        return False
    shown = f"{where}.{c.key_name(name)}" if where else c.key_name(name)
    if not isinstance(name, str):
        problem(shown, f"a group name must be a string, got {c.describe(name)}; quote it")
    else:
        problem(shown, "invalid group name (letters, digits, . _ -)")
    return True
