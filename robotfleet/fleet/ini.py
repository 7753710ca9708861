"""Ansible's INI inventory, read into the fleet's tree (robotfleet/fleet/tree.py)
as Ansible's ini plugin reads it:

    robot[01:03] ansible_host=10.0.0.1   # hosts outside a section are 'ungrouped'
    [robots]                             # a group and its hosts (host patterns)
    robot7 ansible_port=2222 docker_users="['ops']"
    [robots:vars]                        # the group's settings, one a line
    payload_image = reg.example.com/ros/payload:1.4.2
    [sites:children]                     # groups in this group
    robots

Comments start a line with ``#`` or ``;`` (and end a host line after ``#``).
Values are typed as Ansible types them, on host lines and in ``:vars``
alike: Python literals (``2222``, ``True``, ``['ops']``, ``'quoted text'``),
everything else is text, so ``true`` and ``yes`` are text (write ``True``).
A ``:vars`` or ``:children`` section of a group declared nowhere, an unknown
section type and a children loop are refused, as Ansible refuses them; each
problem is one line naming the file and the line.
"""

from __future__ import annotations

import ast
import re
import shlex
import warnings

from robotfleet.fleet.tree import ALL, HOST_NAME, UNGROUPED, Group, Layer, Tree, host_names

SECTION = re.compile(r"^\[([^:\]\s]+)(?::(\w+))?\]\s*(?:#.*)?$")
GROUP_NAME = re.compile(r"^([^:\]\s]+)\s*(?:#.*)?$")
COMMENTS = ("#", ";")


def has_section(text: str) -> bool:
    """Whether a line of ``text`` is an INI section header (``[robots]``,
    ``[all:vars]``): what tells an INI inventory without an extension from
    a YAML one that does not parse."""
    return any(SECTION.match(line.strip()) for line in text.splitlines())


def value(text: str):
    """An INI value as Ansible types it (ast.literal_eval, else the text)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SyntaxWarning)
            parsed = ast.literal_eval(text)
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError):
        return text
    return _plain(parsed)


def _plain(parsed):
    """Ansible's coercions: tuples and sets become lists, complex numbers
    and ``...`` text, bytes text."""
    if isinstance(parsed, (list, tuple, set, frozenset)):
        return [_plain(item) for item in parsed]
    if isinstance(parsed, dict):
        return {_plain(key): _plain(item) for key, item in parsed.items()}
    if parsed is Ellipsis:
        return "..."
    if isinstance(parsed, complex):
        return str(parsed)
    if isinstance(parsed, bytes):
        return parsed.decode("utf-8", "surrogateescape")
    return parsed


def read(text: str, shown: str, tree: Tree, lines: list[str]) -> None:
    """Add the INI inventory ``text`` (named ``shown``) to ``tree``;
    problems appended to ``lines``."""
    Reader(shown, tree, lines).read(text)


class Reader:
    def __init__(self, shown: str, tree: Tree, lines: list[str]):
        self.shown, self.tree, self.lines = shown, tree, lines
        self.declared = {ALL, UNGROUPED, *tree.groups}  # groups of the files read before count as declared
        self.pending: dict[str, tuple[int, str]] = {}  # group -> (line, what refers to it)
        self.edges: list[tuple[str, str, int]] = []  # (parent, child, line)

    def problem(self, number: int, message: str) -> None:
        self.lines.append(f"{self.shown}:{number}: {message}")

    def read(self, text: str) -> None:
        group, kind, layer = UNGROUPED, "hosts", None
        self.group(UNGROUPED)
        for number, raw in enumerate(text.splitlines(), 1):
            line = raw.strip()
            if not line or line.startswith(COMMENTS):
                continue
            section = SECTION.match(line)
            if section:
                group, kind = section.group(1), section.group(2) or "hosts"
                layer = None
                if kind not in ("hosts", "children", "vars"):
                    self.problem(
                        number,
                        f"[{group}:{kind}]: unknown section type {kind!r} "
                        "(a section is [group], [group:vars] or [group:children])",
                    )
                    kind = "skip"
                elif not HOST_NAME.fullmatch(group):
                    self.problem(number, f"[{line.split(']')[0][1:]}]: invalid group name (letters, digits, . _ -)")
                    kind = "skip"
                elif kind == "vars":
                    self.pending.setdefault(group, (number, f"[{group}:vars]"))
                else:
                    self.declared.add(group)
                    self.group(group)
                continue
            if line.startswith("[") and line.endswith("]"):
                self.problem(
                    number,
                    f"{line}: not a section header (no spaces inside the brackets; "
                    "[group], [group:vars] or [group:children])",
                )
                kind = "skip"
                continue
            if kind == "hosts":
                self.host_line(group, line, number)
            elif kind == "vars":
                if layer is None:
                    layer = Layer({}, self.shown, line=number)
                    self.group(group).layers.append(layer)
                self.vars_line(group, layer, line, number)
            elif kind == "children":
                self.child_line(group, line, number)
        self.finish()

    def group(self, name: str) -> Group:
        found = self.tree.groups.setdefault(name, Group(name))
        if name != ALL:
            found.parents.add(ALL)
        return found

    def host_line(self, group: str, line: str, number: int) -> None:
        try:
            tokens = shlex.split(line, comments=True)
        except ValueError as error:
            self.problem(number, f"cannot read this host line: {error} (an unclosed quote?)")
            return
        if not tokens:
            return
        pattern, pairs = tokens[0], tokens[1:]
        if pattern.strip() == "---":
            self.problem(number, "'---' is not a host: is this file YAML? Name it .yaml or .yml")
            return
        values, keys = {}, {}
        for pair in pairs:
            if "=" not in pair:
                self.problem(number, f"{pattern}: expected key=value after the host name, got {pair!r}")
                return
            key, text = pair.split("=", 1)
            values[key] = value(text)
            keys[key] = number

        def problem(where, message):
            self.problem(number, f"{where}: {message}")

        for host, port in host_names(pattern, problem):
            self.tree.listed(host, group, Layer(dict(values), self.shown, dict(keys), number), port)

    def vars_line(self, group: str, layer: Layer, line: str, number: int) -> None:
        if "=" not in line:
            self.problem(number, f"[{group}:vars]: expected key=value, got {line!r}")
            return
        key, text = (part.strip() for part in line.split("=", 1))
        layer.values[key] = value(text)
        layer.lines[key] = number

    def child_line(self, group: str, line: str, number: int) -> None:
        match = GROUP_NAME.match(line)
        if not match or not HOST_NAME.fullmatch(match.group(1)):
            self.problem(number, f"[{group}:children]: expected a group name (letters, digits, . _ -), got {line!r}")
            return
        child = match.group(1)
        if child == ALL:
            self.problem(number, f"[{group}:children]: all cannot be a child group")
            return
        self.pending.setdefault(child, (number, f"[{group}:children]"))
        self.edges.append((group, child, number))

    def finish(self) -> None:
        for name, (number, where) in self.pending.items():
            if name not in self.declared:
                self.problem(
                    number,
                    f"{where} names the group {name!r}, which is declared nowhere "
                    f"(add a [{name}] or [{name}:children] section)",
                )
        for parent, child, number in self.edges:
            if child not in self.declared:
                continue
            if child == parent or child in self.ancestors(parent):
                self.problem(
                    number, f"[{parent}:children]: {child} is already above {parent} (the groups would form a circle)"
                )
                continue
            self.group(child).parents.add(parent)

    def ancestors(self, name: str) -> set[str]:
        """Every group above ``name``."""
        seen, todo = set(), [name]
        while todo:
            current = self.tree.groups.get(todo.pop())
            for above in current.parents if current else ():
                if above not in seen:
                    seen.add(above)
                    todo.append(above)
        return seen
