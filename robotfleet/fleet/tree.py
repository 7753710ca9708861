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

Which hosts are robots and which are laptops stays explicit: a host is a
robot if a group named ``robots`` is above it (at any depth), a laptop if
``laptops`` is; both is refused, neither too.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from robotfleet import checks as c

EXTENSION_PREFIX = "x-"
HOST_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,62}")
GROUP_KEYS = ("vars", "hosts", "children")
ALL = "all"


@dataclass
class Group:
    name: str
    layers: list[dict] = field(default_factory=list)  # its vars, one per definition
    parents: set[str] = field(default_factory=set)


@dataclass
class Tree:
    groups: dict[str, Group] = field(default_factory=dict)
    # host -> (group, its vars there) for each place it is listed, in file order
    hosts: dict[str, list[tuple[str, dict]]] = field(default_factory=dict)
    _depths: dict[str, int] = field(default_factory=dict)

    def above(self, host: str) -> set[str]:
        """Every group ``host`` is in: where it is listed and their ancestors."""
        found: set[str] = set()
        todo = [group for group, _ in self.hosts[host]]
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

    def ordered(self, names: set[str]) -> list[str]:
        """Ansible's order of group vars: all first, then by depth, then by name."""
        return sorted(names, key=lambda name: (name != ALL, self.depth(name), name))


def read(raw: dict, lines: list[str], shown: str) -> Tree:
    """The tree of ``raw`` (the loaded file); problems appended to ``lines``."""
    tree = Tree()
    tree.groups[ALL] = Group(ALL)

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
                problem(f"{name}.{c.key_name(key)}", "unknown key" + c.did_you_mean(str(key), GROUP_KEYS)
                        + "; a group has vars, hosts and children")
        variables = node.get("vars")
        if isinstance(variables, dict):
            group.layers.append(variables)
        elif variables is not None:
            problem(f"{name}.vars", f"expected a mapping of settings, got {c.describe(variables)}")
        hosts = node.get("hosts")
        if isinstance(hosts, dict):
            for host, host_vars in hosts.items():
                if host_name_problem(host, problem):
                    continue
                if host_vars is None:
                    host_vars = {}
                if not isinstance(host_vars, dict):
                    problem(host, f"expected a mapping of settings, got {c.describe(host_vars)}")
                    continue
                tree.hosts.setdefault(host, []).append((name, host_vars))
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


def host_name_problem(name, problem) -> bool:
    if not isinstance(name, str):
        problem(c.key_name(name), f"a host name must be a string, got {c.describe(name)}; quote it")
        return True
    if not HOST_NAME.fullmatch(name):
        problem(c.key_name(name), "invalid host name (letters, digits, . _ -)")
        return True
    return False


def group_name_problem(name, where: str, problem) -> bool:
    if isinstance(name, str) and HOST_NAME.fullmatch(name):
        return False
    shown = f"{where}.{c.key_name(name)}" if where else c.key_name(name)
    if not isinstance(name, str):
        problem(shown, f"a group name must be a string, got {c.describe(name)}; quote it")
    else:
        problem(shown, "invalid group name (letters, digits, . _ -)")
    return True
