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

import functools
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

from roles import checks as c
from roles import fleetyaml, settings

GROUPS = ("robots", "laptops")
# Top-level keys starting with x- are ignored (as in compose files): a place
# for YAML anchors shared with merge keys, e.g. x-camera: &camera {...}.
EXTENSION_PREFIX = "x-"
# 5,000 robots with sensors are about 1 MiB: anything far larger is a mistake.
MAX_BYTES = 32 * 2**20
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


def display_path(path: Path) -> str:
    try:
        return os.path.relpath(path)
    except ValueError:
        return str(path)


def load(path: Path, defaults: dict[str, dict] | None = None) -> Fleet:
    """Parse and check the fleet file; raise FleetError listing every problem."""
    try:
        with path.open("rb") as file:
            data = file.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise FleetError([f"{display_path(path)}: fleet file not found"]) from None
    except OSError as error:
        raise FleetError([f"{display_path(path)}: cannot read the fleet file ({error.strerror})"]) from None
    return parse(data, display_path(path), defaults)


def parse(text: str | bytes, shown: str, defaults: dict[str, dict] | None = None) -> Fleet:
    """Check fleet YAML ``text``, named ``shown`` in problem lines."""
    if len(text) > MAX_BYTES:
        raise FleetError([f"{shown}: larger than {MAX_BYTES // 2**20} MiB; a fleet file is text people edit"])
    try:
        raw = fleetyaml.load(text)
    except fleetyaml.YamlProblem as problem:
        raise FleetError([one_line(f"{shown}: {problem}")]) from None
    return check(raw, shown, _group_data() if defaults is None else defaults)


@functools.lru_cache(maxsize=1)
def _group_data() -> dict[str, dict]:
    return read_group_data()  # read-only below: check() copies what it merges


_CONTROL = {i: f"\\x{i:02x}" for i in [*range(0x20), 0x7F, *range(0x80, 0xA0)]}
_CONTROL.update({0x2028: "\\u2028", 0x2029: "\\u2029"})


def one_line(line: str) -> str:
    """A problem line with any control character (a newline in a host name)
    escaped: one problem is always one line."""
    return line.translate(_CONTROL)


def check(raw, shown: str, defaults: dict[str, dict]) -> Fleet:
    lines: list[str] = []

    def report(where: str, problems):
        for sub, message in problems:
            location = f"{where}.{sub}" if sub and not sub.startswith("[") else f"{where}{sub}"
            lines.append(f"{shown}: {location.strip('.')}: {message}")

    def finish(fleet: Fleet | None = None) -> Fleet:
        if fleet is not None and not lines and not any(fleet.groups.values()):
            lines.append(f"{shown}: no hosts: declare them under robots.hosts or laptops.hosts")
        if lines:
            raise FleetError([one_line(line) for line in lines])
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
                + settings.did_you_mean(str(key), ("all",) + GROUPS)
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
                    f"{shown}: {name}.{c.key_name(key)}: unknown key" + settings.did_you_mean(str(key), allowed)
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
        return settings.normalize(variables), hosts

    def check_vars(where: str, variables: dict) -> set[str]:
        problems = settings.check_layer(variables)
        report(where, problems)
        return {settings.setting_of(sub) for sub, _ in problems}

    all_vars, _ = section("all")
    all_refused = check_vars("all.vars", all_vars)

    fleet = Fleet()
    seen: dict[str, str] = {}
    for group in GROUPS:
        group_vars, hosts = section(group)
        group_refused = all_refused | check_vars(f"{group}.vars", group_vars)
        base = {**defaults.get("all", {}), **defaults.get(group, {}), **all_vars, **group_vars}
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
            host_vars = settings.normalize(host_vars)
            layer_problems = settings.check_layer(host_vars)
            report(name, layer_problems)
            refused = group_refused | {settings.setting_of(sub) for sub, _ in layer_problems}
            if "address" in refused:
                refused.add("ssh_hostname")
            data = {**all_vars, **group_vars, **host_vars}
            settings._services().merge_into(data, [all_vars, group_vars, host_vars])  # per service
            if "address" in data:
                data["ssh_hostname"] = data.pop("address")
            merged = {**base, **host_vars}
            settings._services().merge_into(merged, [all_vars, group_vars, host_vars])  # per service
            if "address" in merged:
                merged["ssh_hostname"] = merged.pop("address")
            report(name, settings.check_host(merged, refused))
            fleet.groups[group].append((name, data))

    return finish(fleet)


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
