"""The part of a gitolite admin repository (``gitolite-admin``, cloned) that
is the fleet's, on a server that also serves a team's other repositories:

    conf/gitolite.conf                  the admin's; robotfleet only appends, once,
                                        include "robotfleet/*.conf"
    conf/robotfleet/<repo>.conf         robotfleet's: the fleet repository's and its
                                        shards' rules, its robots' group (rewritten whole)
    keydir/robotfleet/<repo>/*.pub      the robots' keys (gitolite reads keydir's subdirectories)

Every other line and key stays as it was.  The robots are only the users
with a key in the fleet's own key directory, never a colleague's key
elsewhere in keydir; a robot whose name is already a user outside it (its
rules would be that user's, and that user's the robot's), a group of the
fleet's name defined elsewhere, a link where robotfleet writes or a file of
its name it did not write refuse the change in one line: the layout is not
one robotfleet can add to safely.

An admin repository an older robotfleet wrote whole (its gitolite.conf
begins with OLD_HEADER, every key of keydir/ a robot) is moved to this
layout once: its gitolite-admin block is kept and the include added, and
the keys of the users its ``@robots`` line named move to the fleet's key
directory (the commit names them).  A colleague's key the older version
had made a robot moves too, as it was a robot: move it back to keydir/
(``git mv``) and the next change leaves it alone.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path

INCLUDE = 'include "robotfleet/*.conf"'
OLD_HEADER = "# Written by robotfleet (robotfleet/pull/operator/gitolite.py); edits here are replaced."
HEADER = "# Written by robotfleet (robotfleet/pull/operator/gitolite.py) for the fleet repository {repo}; edits here are replaced."  # noqa: E501
_REPO = re.compile(r"[A-Za-z0-9][-0-9a-zA-Z._+/]*\Z")


class LayoutError(Exception):
    """The admin repository is not one robotfleet can add to safely (one line)."""


def slug(repo: str) -> str:
    if not _REPO.match(repo) or ".." in repo:
        raise LayoutError(f"{repo!r}: not a gitolite repository name robotfleet can keep rules for")
    return repo.replace("/", ".")


def conf_file(repo: str) -> str:
    return f"conf/robotfleet/{slug(repo)}.conf"


def key_dir(repo: str) -> str:
    return f"keydir/robotfleet/{slug(repo)}"


def group(repo: str) -> str:
    """The fleet's robots' gitolite group (a team's own ``@robots`` is not it)."""
    return f"@robotfleet-{slug(repo)}"


def _kind(path: Path) -> str | None:
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return None
    return "link" if stat.S_ISLNK(mode) else "dir" if stat.S_ISDIR(mode) else "file" if stat.S_ISREG(mode) else "other"


def _user(name: str) -> str:
    """gitolite's user of a key file name (``alice@laptop.pub`` is alice)."""
    return name[:-4].split("@", 1)[0]


class Layout:
    """The clone ``work`` of the admin repository, for the fleet repository ``repo``."""

    def __init__(self, work, repo: str):
        self.work, self.repo = Path(work), repo
        self.conf = self.work / conf_file(repo)
        self.keys = self.work / key_dir(repo)
        self.main = self.work / "conf" / "gitolite.conf"

    def check(self) -> None:
        """Refuse (LayoutError) what robotfleet cannot write through or over."""
        if _kind(self.main) != "file":
            raise LayoutError("conf/gitolite.conf: missing or not a regular file (not a gitolite admin repository?)")
        ours = ("conf", "conf/robotfleet", conf_file(self.repo), "keydir", "keydir/robotfleet", key_dir(self.repo))
        for relative in ours:
            kind = _kind(self.work / relative)
            if kind not in (None, "file" if relative.endswith(".conf") else "dir"):
                shown = "a symbolic link" if kind == "link" else f"a {kind}"
                raise LayoutError(f"{relative}: {shown} where robotfleet writes")
        if self.conf.exists() and not self.conf.read_text(errors="replace").startswith(HEADER.format(repo=self.repo)):
            raise LayoutError(f"{conf_file(self.repo)}: not written by robotfleet; move it away first")
        for entry in self.keys.iterdir() if self.keys.is_dir() else ():
            if _kind(entry) != "file":
                raise LayoutError(f"{key_dir(self.repo)}/{entry.name}: not a key file robotfleet wrote")

    def old(self) -> bool:
        """Whether an older robotfleet wrote gitolite.conf whole."""
        return self.main.read_text(errors="replace").startswith(OLD_HEADER)

    def migrate(self, admins) -> list[str]:
        """The older layout moved to this one (see the module's docstring): the users moved."""
        lines = self.main.read_text().splitlines()
        named = next((line.split("=", 1)[1].split() for line in lines if line.startswith("@robots =")), [])
        block, inside = [], False
        for line in lines:
            inside = line.startswith("repo gitolite-admin") or (inside and line.startswith(" "))
            if inside:
                block.append(line)
        self.main.write_text("\n".join(block or ["repo gitolite-admin", f"    RW+ = {' '.join(admins)}"]) + "\n")
        moved = sorted({_user(p.name) for p in self._top_keys() if _user(p.name) in set(named) - set(admins)})
        self.keys.mkdir(parents=True, exist_ok=True)
        for path in self._top_keys():
            if _user(path.name) in moved:
                os.rename(path, self.keys / path.name)
        return moved

    def _top_keys(self) -> list[Path]:
        keydir = self.work / "keydir"
        return sorted(p for p in keydir.glob("*.pub") if _kind(p) == "file") if keydir.is_dir() else []

    def robots(self, admins) -> set[str]:
        """The fleet's robots: the users with a key in its key directory."""
        if not self.keys.is_dir():
            return set()
        return {_user(p.name) for p in self.keys.glob("*.pub")} - set(admins)

    def check_users(self, robots) -> None:
        """Refuse a robot that is already a user outside the fleet's keys, and
        the fleet's group defined anywhere but its own file."""
        robots = set(robots)
        for where, dirs, files in os.walk(self.work / "keydir"):
            here = Path(where)
            if here == self.keys:
                dirs[:] = []
                continue
            for name in sorted(files):
                if name.endswith(".pub") and _user(name) in robots:
                    shown = (here / name).relative_to(self.work)
                    raise LayoutError(
                        f"robot {_user(name)}: {shown} is already the gitolite user {_user(name)} "
                        "outside robotfleet's keys (its rules would be the robot's); rename the robot or that key"
                    )
        defines = re.compile(rf"\s*{re.escape(group(self.repo))}\s*=")
        for path in sorted((self.work / "conf").rglob("*.conf")):
            if path != self.conf and _kind(path) == "file":
                if any(defines.match(line) for line in path.read_text(errors="replace").splitlines()):
                    raise LayoutError(f"{path.relative_to(self.work)}: defines {group(self.repo)}, robotfleet's group")

    def write(self, text: str) -> None:
        """The fleet's rules into its own file; the include appended to gitolite.conf once."""
        self.conf.parent.mkdir(parents=True, exist_ok=True)
        self.conf.write_text(text)
        main = self.main.read_text()
        if INCLUDE not in (line.strip() for line in main.splitlines()):
            joined = main if main.endswith("\n") or not main else main + "\n"
            note = "# the fleet repositories robotfleet keeps (conf/robotfleet/, keydir/robotfleet/)"
            self.main.write_text(f"{joined}\n{note}\n{INCLUDE}\n")
