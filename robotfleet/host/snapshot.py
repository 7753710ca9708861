"""One round trip that reads everything the roles need to know about a host.

pyinfra 3 runs a command per fact per operation (facts are not cached), which
on a robot behind a slow link makes a converged rerun cost dozens of round
trips.  Instead each role declares what it needs (files, packages, users,
units, probes) in a ``SnapshotQuery``; deploy.py reads it all with one command
(``HostSnapshot``), and the roles' operations compare desired state with that
snapshot, yielding commands only for differences.

The snapshot describes the host as it was when the deploy started; each
operation owns distinct things, and dependent steps are chained with ``_if``.

A snapshot answers only what was asked: reading a file, package, user, unit,
command or probe that no role declared raises ``UndeclaredRead``.  Otherwise a
role that forgot to declare a read would see "absent" and change the host on
every run.

The script itself (``snapshot_sh.py``) starts few programs on the host, each
asked once for everything: the same command runs at every deploy and every
pull-mode check.
"""

from __future__ import annotations

import base64
import re
import shlex
from dataclasses import dataclass, field

from pyinfra.api import FactBase

from robotfleet.host import snapshot_sh
from robotfleet.host.snapshot_sh import snapshot_script


@dataclass
class SnapshotQuery:
    files: set[str] = field(default_factory=set)
    packages: set[str] = field(default_factory=set)
    users: set[str] = field(default_factory=set)
    units: set[str] = field(default_factory=set)
    commands: set[str] = field(default_factory=set)
    # name -> shell snippet; its stdout is returned verbatim.
    probes: dict[str, str] = field(default_factory=dict)

    def as_kwargs(self) -> dict:
        return {
            "files": sorted(self.files),
            "packages": sorted(self.packages),
            "users": sorted(self.users),
            "units": sorted(self.units),
            "commands": sorted(self.commands),
            "probes": dict(sorted(self.probes.items())),
        }


class UndeclaredRead(LookupError):
    """A role read a snapshot key it did not declare in ``declare_reads``."""

    def __str__(self) -> str:
        return self.args[0]


class Readings(dict):
    """One kind of snapshot reading (key -> value), limited to the keys the
    query asked for.  A queried key the host lacks reads as absent (``get``
    returns the default, ``in`` is false); an unqueried key raises."""

    def __init__(self, kind: str, queried, values=()):
        super().__init__(values)
        self.kind = kind
        self.queried = frozenset(queried)

    def _check(self, key) -> None:
        if key not in self.queried:
            raise UndeclaredRead(
                f"snapshot: {self.kind} {key!r} was not read from the host; "
                f"add it to the role's declare_reads (query.{self.kind})"
            )

    def __getitem__(self, key):
        self._check(key)
        return super().__getitem__(key)

    def get(self, key, default=None):
        self._check(key)
        return super().get(key, default)

    def __contains__(self, key) -> bool:
        self._check(key)
        return super().__contains__(key)


@dataclass(frozen=True)
class FileState:
    kind: str  # "file", "dir" or "link" (a symlink, whatever it points at)
    sha256: str | None
    mode: str  # octal, e.g. "644"
    owner: str
    group: str


@dataclass
class Snapshot:
    os_release: dict[str, str] = field(default_factory=dict)
    arch: str = ""
    packages: dict[str, str] = field(default_factory=dict)  # installed only: name -> version
    files: dict[str, FileState | None] = field(default_factory=dict)
    users: dict[str, list[str] | None] = field(default_factory=dict)  # None: no such user
    units: dict[str, tuple[str, str]] = field(default_factory=dict)  # (is-enabled, is-active)
    commands: dict[str, str | None] = field(default_factory=dict)
    probes: dict[str, str] = field(default_factory=dict)

    def installed(self, package: str) -> bool:
        return package in self.packages

    def unit_enabled(self, unit: str) -> bool:
        return self.units.get(unit, ("", ""))[0] in ("enabled", "static", "alias")

    def unit_active(self, unit: str) -> bool:
        return self.units.get(unit, ("", ""))[1] == "active"


READING_KINDS = ("packages", "files", "users", "units", "commands", "probes")


_STAT_KINDS = {"symbolic link": "link", "directory": "dir", "regular file": "file", "regular empty file": "file"}
_SHA_LINE = re.compile(r"([0-9a-f]{64})  (/.*)\Z")


def parse(lines: list[str], query: dict) -> Snapshot:
    """The snapshot script's output, answering only the keys of ``query``
    (``SnapshotQuery.as_kwargs()``)."""
    snap = Snapshot(**{kind: Readings(kind, query.get(kind) or ()) for kind in READING_KINDS})
    stats, shas, os_lines, sizes, blob, ones = {}, {}, [], [], b"", {}
    for line in lines:
        kind, _, rest = line.partition("\t")
        parts = rest.split("\t")
        if kind == "osl":
            os_lines.append(rest)
        elif kind == "arch":
            snap.arch = parts[0].strip()
        elif kind == "pkg" and len(parts) >= 3:
            name, status, version = parts[0], parts[1], parts[2]
            if status.endswith(" installed"):
                snap.packages[name] = version
        elif kind == "stat" and len(parts) >= 3:
            stats[parts[0]] = (_STAT_KINDS.get(parts[1]), parts[2])
        elif kind == "file":
            path = parts[0]
            if len(parts) >= 4 and parts[1] in ("file", "dir", "link"):
                mode, owner, group = (parts[3].split() + ["", "", ""])[:3]
                sha = parts[2] if parts[1] == "file" else None
                snap.files[path] = FileState(parts[1], sha, mode, owner, group)
            else:
                snap.files[path] = None
        elif kind == "user":
            snap.users[parts[0]] = None if parts[1] == "-" else parts[1].split()
        elif kind == "unit":
            snap.units[parts[0]] = (parts[1], parts[2] if len(parts) > 2 else "")
        elif kind == "cmd":
            snap.commands[parts[0]] = parts[1] or None if len(parts) > 1 else None
        elif kind == "probe":
            snap.probes[parts[0]] = base64.b64decode(parts[1]).decode() if len(parts) > 1 and parts[1] else ""
        elif kind == "pone" and len(parts) == 2 and parts[0].isdigit():  # one probe's output, by its index
            sizes.append((parts[0], None))
            ones[parts[0]] = base64.b64decode(parts[1]).decode() if parts[1] else ""
        elif kind == "psize" and len(parts) == 2 and parts[1].isdigit():
            sizes.append((parts[0].rsplit("/p", 1)[-1], int(parts[1])))
        elif kind == "pblob":
            blob = base64.b64decode(rest)
        else:
            match = _SHA_LINE.match(line)
            if match:
                shas[match.group(2)] = match.group(1)
    snap.os_release = parse_os_release("\n".join(os_lines))
    names = list(query.get("probes") or {})
    for index, size in sizes:  # the blob: the probes' outputs one after another, in the order of sizes
        if index.isdigit() and int(index) < len(names):
            snap.probes[names[int(index)]] = ones[index] if size is None else blob[:size].decode()
        blob = blob[size or 0 :]
    for name in names:  # cut off by the timeout: unknown, as a failed probe
        snap.probes.setdefault(name, "")
    for path in query.get("files") or ():
        if path in snap.files or not snapshot_sh.PLAIN_PATH.match(path):
            continue
        kind, attributes = stats.get(path, (None, ""))
        if kind is None:  # missing, or neither a file, a directory nor a link
            snap.files[path] = None
            continue
        mode, owner, group = (attributes.split() + ["", "", ""])[:3]
        snap.files[path] = FileState(kind, shas.get(path, "") if kind == "file" else None, mode, owner, group)
    return snap


def parse_os_release(text: str) -> dict[str, str]:
    values = {}
    for line in text.splitlines():
        key, sep, value = line.partition("=")
        if sep and key.strip() and not key.startswith("#"):
            try:
                parts = shlex.split(value)
            except ValueError:
                parts = [value.strip("\"'")]
            values[key.strip().lower()] = parts[0] if parts else ""
    return values


class HostSnapshot(FactBase):
    """Everything the roles need from a host, read in one command."""

    def command(self, files=(), packages=(), users=(), units=(), commands=(), probes=None):
        self.query = {
            "files": files,
            "packages": packages,
            "users": users,
            "units": units,
            "commands": commands,
            "probes": probes or {},
        }
        return snapshot_script(files, packages, users, units, commands, probes)

    def process(self, output):
        return parse(list(output), self.query)

    @staticmethod
    def default():
        return Snapshot()
