"""What a hostile robot can push as its report: git objects made by hand
(a tree where a file belongs, a tree whose bytes read as cat-file records),
pushed to refs/reports/<robot> of a real repository as the robot would."""

from __future__ import annotations

import subprocess
from pathlib import Path


def git(where: Path, *args: str, stdin: bytes | None = None) -> str:
    return (
        subprocess.run(
            ["git", "-C", str(where), *args],
            input=stdin,
            check=True,
            capture_output=True,
            env={
                "GIT_AUTHOR_NAME": "t",
                "GIT_AUTHOR_EMAIL": "t@t",
                "GIT_COMMITTER_NAME": "t",
                "GIT_COMMITTER_EMAIL": "t@t",
                "HOME": str(where),
                "PATH": "/usr/bin:/bin",
            },
        )
        .stdout.decode()
        .strip()
    )


def workspace(where: Path) -> Path:
    subprocess.run(["git", "init", "-q", str(where)], check=True)
    return where


def blob(work: Path, data: bytes) -> str:
    return git(work, "hash-object", "-w", "--stdin", stdin=data)


def forging_tree(work: Path, forged: bytes) -> str:
    """A tree git can walk (one entry: a submodule's commit, never looked
    up) whose bytes, read as the next of ``git cat-file --batch``'s records,
    are a blob record holding ``forged``: "160000 blob <n>\\n<forged>\\n\\0<id>"."""
    raw = b"160000 blob %d\n%s\n\0%s" % (len(forged), forged, b"\x11" * 20)
    return git(work, "hash-object", "-t", "tree", "--literally", "-w", "--stdin", stdin=raw)


def push_report_entry(bare: Path, work: Path, robot: str, entry: str) -> None:
    """Push to refs/reports/<robot> a commit whose root tree holds ``entry``
    (``<mode> <type> <id>\\t<name>``, e.g. a tree named report.json)."""
    tree = git(work, "mktree", stdin=f"{entry}\n".encode())
    commit = git(work, "commit-tree", tree, "-m", f"report of {robot}")
    git(work, "push", "-q", "--force", str(bare), f"{commit}:refs/reports/{robot}")
