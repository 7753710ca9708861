"""The fleet file: load it, check every host's data, hand pyinfra its groups.

The file has the shape of an Ansible YAML inventory (robotfleet/fleet/tree.py):
``all``, groups with ``vars``, ``hosts`` and ``children`` at any depth; the
``robots`` and ``laptops`` groups say which hosts are which.  A host's data
is the settings' defaults < all.vars < the groups above it < the host.
ansible_host, ansible_user, ansible_port and ansible_ssh_private_key_file
are read as address, ssh_user, ssh_port and ssh_key; Ansible's other
variables (ansible_become, ...) configure Ansible itself and are ignored
with a note, so an Ansible inventory works as it is.
Everything is checked before pyinfra connects anywhere; each problem is one
line ``FILE: HOST.FIELD: message``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from robotfleet import checks as c
from robotfleet.fleet import loader, tree
from robotfleet.fleet.registry import Registry, setting_of
from robotfleet.fleet.tree import EXTENSION_PREFIX, HOST_NAME
from robotfleet.role import GROUPS

__all__ = ["EXTENSION_PREFIX", "HOST_NAME", "Fleet", "FleetError", "check", "display_path", "load", "parse"]
# 5,000 robots with sensors are about 1 MiB: anything far larger is a mistake.
MAX_BYTES = 32 * 2**20
ANSIBLE_PREFIX = "ansible_"


class FleetError(Exception):
    def __init__(self, lines: list[str]):
        super().__init__("\n".join(lines))
        self.lines = lines


@dataclass
class Fleet:
    groups: dict[str, list[tuple[str, dict]]] = field(default_factory=dict)  # robots, laptops
    # Every other group of the file (Ansible's), as host names, for --limit.
    subgroups: dict[str, list[str]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def hosts(self, group: str) -> list[tuple[str, dict]]:
        return self.groups.get(group, [])


def display_path(path: Path) -> str:
    try:
        return os.path.relpath(path)
    except ValueError:
        return str(path)


def load(path: Path, registry: Registry) -> Fleet:
    """Parse and check the fleet file; raise FleetError listing every problem."""
    try:
        with path.open("rb") as file:
            data = file.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise FleetError([f"{display_path(path)}: fleet file not found"]) from None
    except OSError as error:
        raise FleetError([f"{display_path(path)}: cannot read the fleet file ({error.strerror})"]) from None
    return parse(data, display_path(path), registry)


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
    lines: list[str] = []
    ignored: set[str] = set()

    def report(where: str, problems):
        for sub, message in problems:
            location = f"{where}.{sub}" if sub and not sub.startswith("[") else f"{where}{sub}"
            lines.append(f"{shown}: {location.strip('.')}: {message}")

    def finish(fleet: Fleet | None = None) -> Fleet:
        if fleet is not None and not lines and not any(fleet.groups.values()):
            lines.append(f"{shown}: no hosts: declare them under robots.hosts or laptops.hosts")
        if lines:
            raise FleetError([c.one_line(line) for line in lines])
        return fleet

    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        lines.append(f"{shown}: expected a mapping with all/robots/laptops at the top, got {c.describe(raw)}")
        finish()
    groups = tree.read(raw, lines, shown)

    def checked(where: str, layer: dict) -> tuple[dict, set[str]]:
        """A layer's settings under their own names (aliases and Ansible's
        names resolved), and the settings it has problems with."""
        own = {}
        for key in layer:
            if isinstance(key, str) and key.startswith(ANSIBLE_PREFIX) and key not in registry.aliases:
                ignored.add(key)
            else:
                own[key] = layer[key]
        problems = registry.check_layer(own)
        report(where, problems)
        refused = {registry.aliases.get(setting_of(sub), setting_of(sub)) for sub, _ in problems}
        named: dict = {}
        for key, value in own.items():
            name = registry.aliases.get(key, key) if isinstance(key, str) else key
            if name in named:
                report(where, [(c.key_name(key), f"sets {name} a second time in the same place; keep one")])
                refused.add(name)
            named[name] = value
        return named, refused

    group_layers: dict[str, list[tuple[dict, set[str]]]] = {
        name: [checked(f"{name}.vars", layer) for layer in group.layers] for name, group in groups.groups.items()
    }
    fleet = Fleet(groups={group: [] for group in GROUPS})
    defaults: dict[str, dict] = {}  # per kind of host, made when a host of that kind is checked
    for name, listed in groups.hosts.items():
        above = groups.above(name)
        kinds = [group for group in GROUPS if group in above]
        if len(kinds) > 1:
            lines.append(f"{shown}: {name}: declared in both {' and '.join(kinds)}")
            continue
        if not kinds:
            where = sorted(above - {tree.ALL}) or [tree.ALL]
            lines.append(f"{shown}: {name}: in neither a robots nor a laptops group (groups: {', '.join(where)})"
                         + c.did_you_mean(where[-1], GROUPS))
            continue
        layers, refused = [], set()
        for group in groups.ordered(above):
            for layer, bad in group_layers[group]:
                layers.append(layer)
                refused |= bad
        for _, host_vars in listed:
            layer, bad = checked(name, host_vars)
            layers.append(layer)
            refused |= bad
        if "ssh_hostname" in refused:
            refused.add("address")
        data = registry.merge(layers)
        if kinds[0] not in defaults:
            defaults[kinds[0]] = registry.defaults(kinds[0])
        merged = {**defaults[kinds[0]], **data}
        report(name, registry.check_host(merged, refused))
        fleet.groups[kinds[0]].append((name, data))
        for group in above - {tree.ALL, *GROUPS}:
            fleet.subgroups.setdefault(group, []).append(name)
    if ignored:
        fleet.notes.append(f"{shown}: note: {', '.join(sorted(ignored))}: Ansible's own, ignored here")
    return finish(fleet)
