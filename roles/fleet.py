"""The fleet file: load it, check every host's data, hand pyinfra its groups.

Layout of the YAML file (Ansible-inventory-like)::

    all:      {vars: {...}}                 # every host
    robots:   {vars: {...}, hosts: {robot1: {address: ..., ...}}}
    laptops:  {vars: {...}, hosts: {...}}

A host's data is group_data defaults < all.vars < group vars < host.
Everything is checked before pyinfra connects anywhere; each problem is one
line ``FILE: HOST.FIELD: message``.
"""

from __future__ import annotations

import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from roles import settings

GROUPS = ("robots", "laptops")
HOST_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,62}")
GROUP_DATA_DIR = Path(__file__).resolve().parent.parent / "group_data"


class FleetError(Exception):
    def __init__(self, lines: list[str]):
        super().__init__("\n".join(lines))
        self.lines = lines


@dataclass
class Fleet:
    groups: dict[str, list[tuple[str, dict]]] = field(default_factory=dict)

    def hosts(self, group: str) -> list[tuple[str, dict]]:
        return self.groups.get(group, [])


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys (a silently lost robot is worse)."""

    def construct_mapping(self, node, deep=False):
        seen = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r}", key_node.start_mark
                )
            seen[key] = True
        return super().construct_mapping(node, deep=deep)


def read_group_data(directory: Path = GROUP_DATA_DIR) -> dict[str, dict]:
    """The defaults pyinfra will load from group_data/, keyed by group."""
    defaults = {}
    for path in sorted(directory.glob("*.py")):
        namespace: dict = {}
        exec(compile(path.read_text(), str(path), "exec"), namespace)
        defaults[path.stem] = {
            k: v
            for k, v in namespace.items()
            if not k.startswith("_") and not callable(v) and type(v).__name__ != "module"
        }
    return defaults


def _setting(field: str) -> str:
    """The setting a problem's field belongs to: sensors[1].serial -> sensors."""
    return field.split(".")[0].split("[")[0]


def display_path(path: Path) -> str:
    try:
        return os.path.relpath(path)
    except ValueError:
        return str(path)


def load(path: Path, defaults: dict[str, dict] | None = None) -> Fleet:
    """Parse and check the fleet file; raise FleetError listing every problem."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise FleetError([f"{display_path(path)}: fleet file not found"]) from None
    return parse(text, display_path(path), defaults)


def parse(text: str, shown: str, defaults: dict[str, dict] | None = None) -> Fleet:
    """Check fleet YAML ``text``, named ``shown`` in problem lines."""
    try:
        raw = yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None) or getattr(error, "context_mark", None)
        where = f"line {mark.line + 1}: " if mark else ""
        problem = getattr(error, "problem", None) or str(error)
        raise FleetError([f"{shown}: {where}YAML error: {problem}"]) from None
    return check(raw, shown, read_group_data() if defaults is None else defaults)


def check(raw, shown: str, defaults: dict[str, dict]) -> Fleet:
    lines: list[str] = []

    def report(where: str, problems):
        for sub, message in problems:
            location = f"{where}.{sub}" if sub and not sub.startswith("[") else f"{where}{sub}"
            lines.append(f"{shown}: {location.strip('.')}: {message}")

    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise FleetError([f"{shown}: expected a mapping with all/robots/laptops at the top"])
    for key in raw:
        if key not in ("all",) + GROUPS:
            lines.append(
                f"{shown}: {key}: unknown top-level key"
                + settings.did_you_mean(str(key), ("all",) + GROUPS)
                + "; expected all, robots or laptops"
            )

    def section(name):
        value = raw.get(name) or {}
        if not isinstance(value, dict):
            lines.append(f"{shown}: {name}: expected a mapping with vars and hosts")
            return {}, {}
        allowed = ("vars",) if name == "all" else ("vars", "hosts")
        for key in value:
            if key not in allowed:
                lines.append(
                    f"{shown}: {name}.{key}: unknown key" + settings.did_you_mean(str(key), allowed)
                )
        variables = value.get("vars") or {}
        if not isinstance(variables, dict):
            lines.append(f"{shown}: {name}.vars: expected a mapping of settings")
            variables = {}
        hosts = value.get("hosts") or {}
        if not isinstance(hosts, dict):
            lines.append(f"{shown}: {name}.hosts: expected a mapping of host name to settings")
            hosts = {}
        return variables, hosts

    all_vars, _ = section("all")
    report("all.vars", settings.check_layer(all_vars))

    fleet = Fleet()
    seen: dict[str, str] = {}
    for group in GROUPS:
        group_vars, hosts = section(group)
        report(f"{group}.vars", settings.check_layer(group_vars))
        fleet.groups[group] = []
        for name, host_vars in hosts.items():
            name = str(name)
            if not HOST_NAME.fullmatch(name):
                lines.append(f"{shown}: {name}: invalid host name (letters, digits, . _ -)")
                continue
            if name in seen:
                lines.append(f"{shown}: {name}: declared in both {seen[name]} and {group}")
                continue
            seen[name] = group
            if host_vars is None:
                host_vars = {}
            if not isinstance(host_vars, dict):
                lines.append(f"{shown}: {name}: expected a mapping of settings")
                continue
            layer_problems = settings.check_layer(host_vars)
            report(name, layer_problems)
            data = {**all_vars, **group_vars, **host_vars}
            settings._services().merge_into(data, [all_vars, group_vars, host_vars])  # per service
            if "address" in data:
                data["ssh_hostname"] = data.pop("address")
            merged = {**defaults.get("all", {}), **defaults.get(group, {}), **data}
            flagged = {_setting(sub) for sub, _ in layer_problems}
            report(name, [p for p in settings.check_host(merged) if _setting(p[0]) not in flagged])
            fleet.groups[group].append((name, data))

    if lines:
        raise FleetError(lines)
    return fleet


def refuse(lines: list[str]) -> None:
    """Stop the pyinfra run before any connection: the lines, exit status 2.
    (os._exit: pyinfra would turn an exception here into a traceback.)"""
    for line in lines:
        print(line, file=sys.stderr)
    sys.stderr.flush()
    os._exit(2)


def load_or_exit(path: Path) -> Fleet:
    """For inventory files: print the problems and stop before any connection."""
    try:
        return load(path)
    except FleetError as error:
        refuse(error.lines + [f"{len(error.lines)} problem(s) in the fleet file; no host was contacted."])
