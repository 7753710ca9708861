"""The fleet file: load it, check every host's data, hand pyinfra its groups.

Layout of the YAML file (Ansible-inventory-like)::

    all:      {vars: {...}}                 # every host
    robots:   {vars: {...}, hosts: {robot1: {address: ..., ...}}}
    laptops:  {vars: {...}, hosts: {...}}

A host's data is the settings' defaults < all.vars < group vars < host.
Everything is checked before pyinfra connects anywhere; each problem is one
line ``FILE: HOST.FIELD: message``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from engine import checks as c
from engine.fleet import loader
from engine.fleet.registry import Registry, setting_of
from engine.role import GROUPS

# Top-level keys starting with x- are ignored (as in compose files): a place
# for YAML anchors shared with merge keys, e.g. x-camera: &camera {...}.
EXTENSION_PREFIX = "x-"
# 5,000 robots with sensors are about 1 MiB: anything far larger is a mistake.
MAX_BYTES = 32 * 2**20
HOST_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,62}")


class FleetError(Exception):
    def __init__(self, lines: list[str]):
        super().__init__("\n".join(lines))
        self.lines = lines


@dataclass
class Fleet:
    groups: dict[str, list[tuple[str, dict]]] = field(default_factory=dict)

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
    for key in raw:
        if isinstance(key, str) and key.startswith(EXTENSION_PREFIX):
            continue
        if not isinstance(key, str) or key not in ("all",) + GROUPS:
            lines.append(
                f"{shown}: {c.key_name(key)}: unknown top-level key"
                + c.did_you_mean(str(key), ("all",) + GROUPS)
                + "; expected all, robots or laptops (or x-... for YAML anchors)"
            )

    def section(name):
        value = raw.get(name)
        if value is None:
            return {}, {}
        if not isinstance(value, dict):
            lines.append(f"{shown}: {name}: expected a mapping with vars and hosts, got {c.describe(value)}")
            return {}, {}
        allowed = ("vars",) if name == "all" else ("vars", "hosts")
        for key in value:
            if key not in allowed:
                lines.append(
                    f"{shown}: {name}.{c.key_name(key)}: unknown key" + c.did_you_mean(str(key), allowed)
                )
        variables = value.get("vars")
        if variables is None:
            variables = {}
        elif not isinstance(variables, dict):
            lines.append(f"{shown}: {name}.vars: expected a mapping of settings, got {c.describe(variables)}")
            variables = {}
        hosts = value.get("hosts")
        if hosts is None:
            hosts = {}
        elif not isinstance(hosts, dict):
            lines.append(f"{shown}: {name}.hosts: expected a mapping of host name to settings, got {c.describe(hosts)}")
            hosts = {}
        return variables, hosts

    def check_vars(where: str, variables: dict) -> set[str]:
        problems = registry.check_layer(variables)
        report(where, problems)
        return {setting_of(sub) for sub, _ in problems}

    all_vars, _ = section("all")
    all_refused = check_vars("all.vars", all_vars)

    fleet = Fleet()
    seen: dict[str, str] = {}
    for group in GROUPS:
        group_vars, hosts = section(group)
        group_refused = all_refused | check_vars(f"{group}.vars", group_vars)
        defaults = registry.defaults(group)
        fleet.groups[group] = []
        for name, host_vars in hosts.items():
            if not isinstance(name, str):
                lines.append(f"{shown}: {c.key_name(name)}: a host name must be a string, got {c.describe(name)}; quote it")
                continue
            if not HOST_NAME.fullmatch(name):
                lines.append(f"{shown}: {c.key_name(name)}: invalid host name (letters, digits, . _ -)")
                continue
            if name in seen:
                lines.append(f"{shown}: {name}: declared in both {seen[name]} and {group}")
                continue
            seen[name] = group
            if host_vars is None:
                host_vars = {}
            if not isinstance(host_vars, dict):
                lines.append(f"{shown}: {name}: expected a mapping of settings, got {c.describe(host_vars)}")
                continue
            layer_problems = registry.check_layer(host_vars)
            report(name, layer_problems)
            refused = group_refused | {setting_of(sub) for sub, _ in layer_problems}
            if "address" in refused:
                refused.add("ssh_hostname")
            data = registry.merge([all_vars, group_vars, host_vars])
            for alias, setting in registry.aliases.items():
                if alias in data:
                    data[setting] = data.pop(alias)
            merged = {**defaults, **data}
            report(name, registry.check_host(merged, refused))
            fleet.groups[group].append((name, data))

    return finish(fleet)


