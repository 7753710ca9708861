"""Where a fleet comes from: an inventory file (YAML or INI) or an inventory
directory, and the ``group_vars/`` and ``host_vars/`` beside it, as Ansible
finds them.

- A file ending in .yaml, .yml or .json is YAML; .ini is INI; a file with
  no (or another) extension is INI when its first line that is not a comment
  is a section header (``[robots]``), else YAML.
- A directory is an inventory made of its files, in name order, as
  ``ansible -i DIR`` reads it: hidden files, ``group_vars``/``host_vars``
  and Ansible's ignored extensions (.md, .txt, .cfg, .retry, .orig, .bak,
  ~, ...) are skipped, sub-directories are read too.
- ``group_vars/`` and ``host_vars/`` beside a file (in a directory: inside
  it) hold settings per group and host: for each name, a directory of that
  name (its files in name order, sub-directories too), else the first of
  NAME, NAME.yml, NAME.yaml, NAME.json; ``all`` is the all group.  Their
  precedence is Ansible's (robotfleet/fleet/tree.py ``Tree.layers``).

What Ansible reads but we cannot (a vault-encrypted file, a dynamic
inventory script, an inventory plugin's configuration) is refused in one
line saying what to do; a vars file we would not read (it names no group or
host of the inventory, or a directory shadows it) is a note, never silent.
"""

from __future__ import annotations

import os
from pathlib import Path

from robotfleet import checkers as c
from robotfleet.fleet import ini, loader, tree

MAX_BYTES = 32 * 2**20  # 5,000 robots with sensors are about 1 MiB: anything far larger is a mistake
YAML_SUFFIXES = (".yaml", ".yml", ".json")
VARS_SUFFIXES = (".yml", ".yaml", ".json")
# Ansible's INVENTORY_IGNORE_EXTS (REJECT_EXTS + .orig, .cfg, .retry)
IGNORED_SUFFIXES = (".pyc", ".pyo", ".swp", ".bak", "~", ".rpm", ".md", ".txt", ".rst", ".orig", ".cfg", ".retry")
VARS_DIRS = ("group_vars", "host_vars")
VAULT = b"$ANSIBLE_VAULT;"
CONVERT = "ansible-inventory -i {0} --list -y > fleet.yaml"


def display_path(path: Path) -> str:
    """A path as the user gave it (absolute stays absolute: /srv/fleets/robots.yaml
    is not ../../srv/fleets/robots.yaml), and the files found under it below it."""
    return str(path)


class Reading:
    """One fleet being read: its tree, problems and notes."""

    def __init__(self):
        self.tree = tree.Tree()
        self.lines: list[str] = []
        self.notes: list[str] = []

    def problem(self, shown: str, message: str) -> None:
        self.lines.append(c.one_line(f"{shown}: {message}"))

    # -- inventory files --------------------------------------------------

    def inventory(self, path: Path) -> None:
        """Read the inventory at ``path`` (a file or a directory) and the
        vars files beside it."""
        if path.is_dir():
            files = list(self.inventory_files(path))
            if not files and not self.lines:
                self.problem(
                    display_path(path),
                    "an inventory directory with no inventory file in it (hosts, hosts.ini, hosts.yaml, ...)",
                )
            for file in files:
                self.file(file)
            base = path
        elif path.suffix == ".py" and path.is_file():
            self.problem(
                display_path(path),
                "a pyinfra inventory (Python), not a fleet file: $ROBOT_FLEET and "
                "--fleet name the fleet (inventories/robots.yaml, or an Ansible "
                "inventory file or directory)",
            )
            return
        else:
            self.file(path)
            base = path.parent
        self.vars_files(base)

    def inventory_files(self, directory: Path, top: bool = True):
        for entry in sorted(os.listdir(directory)):
            path = directory / entry
            if entry in VARS_DIRS and not top and path.is_dir():
                self.notes.append(
                    f"{display_path(path)}: note: not read: Ansible reads group_vars/ and host_vars/ "
                    "at the top of an inventory directory only"
                )
            if entry.startswith(".") or entry in VARS_DIRS or entry.endswith(IGNORED_SUFFIXES):
                continue
            if path.is_dir():
                yield from self.inventory_files(path, top=False)
            else:
                yield path

    def file(self, path: Path) -> None:
        shown = display_path(path)
        data = self.read_bytes(path, "fleet file")
        if data is None:
            return
        if data.startswith(b"#!"):
            self.problem(
                shown,
                "a dynamic inventory script: robotfleet reads static inventories; write its "
                f"output to a file: {CONVERT.format(shown)}",
            )
            return
        if data.startswith(VAULT):
            self.problem(
                shown,
                "encrypted with ansible-vault, which robotfleet does not read: "
                f"ansible-vault view {shown} > fleet.yaml (and keep it safe)",
            )
            return
        if path.suffix == ".toml":
            self.problem(shown, f"a TOML inventory is not read here: convert it: {CONVERT.format(shown)}")
            return
        text = self.decode(data, shown)
        if text is None:
            return
        if path.suffix == ".ini":
            ini.read(text, shown, self.tree, self.lines)
            return
        places: dict = {}
        try:
            raw = loader.load(text, places)
        except loader.YamlProblem as problem:
            if path.suffix not in YAML_SUFFIXES and ini.has_section(text):
                ini.read(text, shown, self.tree, self.lines)
            else:
                self.problem(shown, str(problem))
            return
        if not isinstance(raw, (dict, type(None))) and path.suffix not in YAML_SUFFIXES and ini.has_section(text):
            ini.read(text, shown, self.tree, self.lines)
            return
        self.yaml_inventory(raw, shown, places)

    def yaml_inventory(self, raw, shown: str, places: dict) -> None:
        if raw is None:
            raw = {}
        if not isinstance(raw, dict):
            self.problem(shown, f"expected a mapping with all/robots/laptops at the top, got {c.describe(raw)}")
            return
        if "plugin" in raw and not isinstance(raw.get("plugin"), dict):
            self.problem(
                shown,
                f"an inventory plugin's configuration (plugin: {c.describe(raw['plugin'])}): "
                f"robotfleet reads static inventories; write the plugin's output to a file: "
                f"{CONVERT.format(shown)}",
            )
            return
        tree.read(raw, self.lines, shown, self.tree, places)

    def read_bytes(self, path: Path, what: str) -> bytes | None:
        shown = display_path(path)
        try:
            with path.open("rb") as file:
                data = file.read(MAX_BYTES + 1)
        except FileNotFoundError:
            self.problem(shown, f"{what} not found")
            return None
        except OSError as error:
            self.problem(shown, f"cannot read the {what} ({error.strerror})")
            return None
        if len(data) > MAX_BYTES:
            self.problem(shown, f"larger than {MAX_BYTES // 2**20} MiB; a fleet file is text people edit")
            return None
        return data

    def decode(self, data: bytes, shown: str) -> str | None:
        try:
            return data.decode("utf-8")
        except UnicodeDecodeError as error:
            line = data.count(b"\n", 0, error.start) + 1
            self.problem(f"{shown}:{line}", f"not UTF-8 text (byte 0x{data[error.start]:02x}); save the file as UTF-8")
            return None

    # -- group_vars/ and host_vars/ -----------------------------------------

    def vars_files(self, base: Path) -> None:
        for kind in VARS_DIRS:
            directory = base / kind
            if not directory.exists():
                continue
            if not directory.is_dir():
                self.notes.append(f"{display_path(directory)}: note: not a directory, not read")
                continue
            known = set(self.tree.groups) if kind == "group_vars" else set(self.tree.hosts)
            used: set[str] = set()
            for name in sorted(known):
                files = self.vars_for(directory, name, used)
                layers = [layer for layer in (self.vars_file(f, kind, name) for f in files) if layer is not None]
                if kind == "group_vars":
                    self.tree.groups[name].files.extend(layers)
                elif layers:
                    self.tree.host_files.setdefault(name, []).extend(layers)
            self.unread(directory, kind, known, used)

    @staticmethod
    def vars_for(directory: Path, name: str, used: set[str]) -> list[Path]:
        """Ansible's find_vars_files: NAME (a directory or a file), else the
        first of NAME.yml, NAME.yaml, NAME.json."""
        for candidate in [name] + [name + suffix for suffix in VARS_SUFFIXES]:
            path = directory / candidate
            if path.is_dir():
                used.add(candidate)
                return list(_dir_files(path))
            if path.is_file():
                used.add(candidate)
                return [path]
        return []

    def vars_file(self, path: Path, kind: str, name: str) -> tree.Layer | None:
        shown = display_path(path)
        data = self.read_bytes(path, "vars file")
        if data is None:
            return None
        if data.startswith(VAULT):
            self.problem(
                shown,
                "encrypted with ansible-vault, which robotfleet does not read: decrypt it "
                f"(ansible-vault decrypt {shown}) or move the fleet's settings out of it",
            )
            return None
        text = self.decode(data, shown)
        if text is None:
            return None
        places: dict = {}
        try:
            values = loader.load(text, places)
        except loader.YamlProblem as problem:
            self.problem(shown, str(problem))
            return None
        if values is None:
            return None  # an empty file, as Ansible skips it
        if not isinstance(values, dict):
            self.problem(shown, f"expected a mapping of settings for the {kind[:-5]} {name}, got {c.describe(values)}")
            return None
        return tree.Layer(values, shown, places=places.get(id(values), {}))

    def unread(self, directory: Path, kind: str, known: set[str], used: set[str]) -> None:
        """A note for each entry of ``directory`` that is not read: it names no
        group (host) of the inventory, has another extension, or another
        entry of the same name is read instead."""
        what = "group" if kind == "group_vars" else "host"
        for entry in sorted(os.listdir(directory)):
            if entry.startswith(".") or entry.endswith("~") or entry in used:
                continue
            path = directory / entry
            suffix = next((x for x in VARS_SUFFIXES if entry.endswith(x)), "")
            stem = entry[: len(entry) - len(suffix)]
            shown = display_path(path)
            if suffix == "" and "." in entry and not path.is_dir():
                self.notes.append(f"{shown}: note: not read: a vars file ends in .yml, .yaml or .json, or has none")
            elif stem in known:
                read = next(u for u in [stem, *(stem + x for x in VARS_SUFFIXES)] if u in used)
                self.notes.append(
                    f"{shown}: note: not read: {kind}/{read} is read for the {what} {stem} instead "
                    "(Ansible reads the first of NAME/, NAME, NAME.yml, NAME.yaml, NAME.json); "
                    "merge them"
                )
            else:
                self.notes.append(
                    f"{shown}: note: no {what} {stem!r} in the inventory"
                    + c.did_you_mean(stem, sorted(known))
                    + "; not read"
                )


def _dir_files(path: Path):
    """Ansible's _get_dir_vars_files: name order, sub-directories without an
    extension too, files with no extension or a vars one; hidden and ~ skipped."""
    for entry in sorted(os.listdir(path)):
        if entry.startswith(".") or entry.endswith("~"):
            continue
        full = path / entry
        suffix = os.path.splitext(entry)[1]
        if full.is_dir() and not suffix:
            yield from _dir_files(full)
        elif full.is_file() and (not suffix or suffix in VARS_SUFFIXES):
            yield full
