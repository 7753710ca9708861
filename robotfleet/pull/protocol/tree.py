"""The deploy tree of a release: which paths it holds, its content hash,
and its code archive (both sides compute the same hash).

The content hash is sha256 over the tree's files sorted by path, each as
``<mode> <sha256 of its content> <path>\\0`` (mode as git writes it: 100644,
100755, or 120000 for a symbolic link, whose content is its target).  The
operator computes it from the commit (git's objects), the robot from the
unpacked archive: a TUF-verified archive whose files hash the same is the
commit's tree, without trusting git's SHA-1 or having its history.

The archive is ``git archive`` of the commit limited to DEPLOY_PATHS, as a
tar compressed here with gzip's header time 0: the same commit gives the
same bytes on the same machine (TUF binds the bytes, so a re-publish of an
unchanged commit adds no new blob to the releases branch).
"""

from __future__ import annotations

import gzip
import hashlib
import os
import shutil
import stat
import subprocess
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path

from robotfleet import atomicfile

# What a robot needs to run the deploy (not tests/ or docs/).
DEPLOY_PATHS = (
    "deploy.py",
    "config.py",
    "rollback.py",
    "pyproject.toml",
    "robotfleet",
    "roles",
    "inventories",
    "group_data",
    "files",
)
FILE, EXECUTABLE, LINK = "100644", "100755", "120000"
GIT_TIMEOUT = 300


class TreeError(Exception):
    """The tree or archive cannot be used; the message is one line."""


@dataclass(frozen=True, order=True)
class Entry:
    path: str
    mode: str
    sha256: str


def tree_sha256(entries) -> str:
    """The content hash of a tree given as entries (any order)."""
    digest = hashlib.sha256()
    for entry in sorted(entries, key=lambda e: e.path.encode()):
        digest.update(f"{entry.mode} {entry.sha256} {entry.path}".encode() + b"\0")
    return digest.hexdigest()


def git(checkout, *args: str, stdin: bytes | None = None) -> bytes:
    """``git -C checkout args`` -> stdout; TreeError with git's last line if it fails."""
    try:
        done = subprocess.run(
            ["git", "-C", str(checkout), *args], input=stdin, capture_output=True, timeout=GIT_TIMEOUT, check=False
        )
    except (OSError, subprocess.TimeoutExpired) as error:
        raise TreeError(f"git {args[0]}: {error}") from None
    if done.returncode:
        said = done.stderr.decode(errors="replace").strip().splitlines()
        raise TreeError(f"git {' '.join(args[:2])}: {said[-1] if said else f'exit status {done.returncode}'}")
    return done.stdout


def resolve(checkout, revision: str) -> str:
    """The commit id of ``revision`` in ``checkout``."""
    return git(checkout, "rev-parse", "--verify", "--quiet", f"{revision}^{{commit}}").decode().strip()


def present(checkout, commit: str, paths=DEPLOY_PATHS) -> list[str]:
    """Those of ``paths`` the commit has."""
    listed = git(checkout, "ls-tree", "-z", "--name-only", commit, "--", *paths).split(b"\0")
    return [p.decode() for p in listed if p]


def blob(checkout, commit: str, path: str) -> bytes:
    """The content of ``path`` at ``commit``."""
    return git(checkout, "cat-file", "blob", f"{commit}:{path}")


def entries_of_commit(checkout, commit: str, paths=DEPLOY_PATHS) -> list[Entry]:
    """The files of ``paths`` at ``commit``, from git's objects."""
    listing = git(checkout, "ls-tree", "-r", "-z", "--full-tree", commit, "--", *paths)
    rows = []
    for item in filter(None, listing.split(b"\0")):
        meta, _, path = item.partition(b"\t")
        mode, kind, obj = meta.decode().split()
        if kind != "blob":
            raise TreeError(
                f"{path.decode(errors='replace')}: a {kind} (submodule) in the deploy tree; a release holds files only"
            )
        rows.append((path.decode(errors="surrogateescape"), mode, obj))
    if not rows:
        return []
    batch = git(checkout, "cat-file", "--batch", stdin=b"".join(f"{obj}\n".encode() for _, _, obj in rows))
    entries, at = [], 0
    for path, mode, _ in rows:
        header_end = batch.index(b"\n", at)
        size = int(batch[at:header_end].split()[2])
        content = batch[header_end + 1 : header_end + 1 + size]
        at = header_end + 1 + size + 1
        entries.append(
            Entry(
                path,
                LINK if mode == LINK else EXECUTABLE if mode == EXECUTABLE else FILE,
                hashlib.sha256(content).hexdigest(),
            )
        )
    return entries


def entries_of_directory(root) -> list[Entry]:
    """The files under ``root`` (an unpacked archive), as git would list them."""
    entries = []
    root = os.fspath(root)
    for directory, dirs, files in os.walk(root):
        dirs.sort()
        for name in sorted(files) + sorted(d for d in dirs if os.path.islink(os.path.join(directory, d))):
            full = os.path.join(directory, name)
            path = os.path.relpath(full, root).replace(os.sep, "/")
            info = os.lstat(full)
            if stat.S_ISLNK(info.st_mode):
                entries.append(Entry(path, LINK, hashlib.sha256(os.fsencode(os.readlink(full))).hexdigest()))
            elif stat.S_ISREG(info.st_mode):
                with open(full, "rb") as handle:
                    digest = (
                        hashlib.file_digest(handle, "sha256").hexdigest()
                        if hasattr(hashlib, "file_digest")
                        else hashlib.sha256(handle.read()).hexdigest()
                    )
                entries.append(Entry(path, EXECUTABLE if info.st_mode & 0o111 else FILE, digest))
    return entries


def write_archive(checkout, commit: str, out, paths=DEPLOY_PATHS) -> str:
    """Write the code archive of ``commit`` to the path ``out`` (temp file,
    then rename); its sha256."""
    listed = present(checkout, commit, paths)
    if not listed:
        raise TreeError(f"commit {commit[:12]} has none of {', '.join(paths)}: not a deploy repository")
    tar = git(checkout, "archive", "--format=tar", commit, "--", *listed)
    with (
        atomicfile.replacing(out, 0o644, make_parents=True) as raw,
        gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0, compresslevel=9) as packed,
    ):
        packed.write(tar)
    with open(out, "rb") as handle:
        return hashlib.sha256(handle.read()).hexdigest()


def _member_problem(member: tarfile.TarInfo) -> str | None:
    name = member.name
    parts = name.split("/")
    if name.startswith("/") or ".." in parts or "\\" in name or not name.strip("/"):
        return f"{name!r}: a path outside the archive's directory"
    if member.issym():
        target = member.linkname
        depth = len([p for p in parts[:-1] if p not in ("", ".")])
        up = 0
        for part in target.split("/"):
            up += -1 if part == ".." else (0 if part in ("", ".") else 1)
            if up < -depth:
                return f"{name!r}: a link pointing outside the archive's directory ({target})"
        if target.startswith("/"):
            return f"{name!r}: a link to an absolute path ({target})"
    elif not (member.isfile() or member.isdir()) and member.type != tarfile.XGLTYPE:
        return f"{name!r}: not a file, directory or link"
    return None


def _through_link(top: Path, name: str) -> str | None:
    """A member whose path passes through (or is) a link already unpacked:
    a link's depth is counted from its name, so its name's directories must
    be real ones (``l -> .`` then ``l/l/up -> ../..`` would leave the tree)."""
    at = top
    for part in (p for p in name.split("/") if p not in ("", ".")):
        at = at / part
        try:
            if stat.S_ISLNK(os.lstat(at).st_mode):
                return f"{name!r}: a path through the link {str(at.relative_to(top))!r}"
        except FileNotFoundError:
            return None
    return None


def _link_leaving(top: Path) -> str | None:
    """Once everything is unpacked: a link that resolves outside ``top``
    through other links (each link alone was checked by its text)."""
    real = os.path.realpath(top)
    for directory, dirs, files in os.walk(top):
        for name in dirs + files:
            path = os.path.join(directory, name)
            if os.path.islink(path) and os.path.commonpath([real, os.path.realpath(path)]) != real:
                shown = os.path.relpath(path, top)
                return f"{shown!r}: a link resolving outside the archive's directory ({os.readlink(path)})"
    return None


def unpack(archive, destination) -> None:
    """Unpack a code archive into ``destination`` (which must not exist):
    into a temp directory beside it, then renamed.  Anything that is not a
    plain file, directory or link inside the tree is refused (TreeError), as
    is a path through a link and a link that other links take outside."""
    destination = Path(destination)
    if destination.exists():
        raise TreeError(f"{destination}: already exists")
    temp = Path(tempfile.mkdtemp(dir=destination.parent, prefix=f".{destination.name}."))
    try:
        with tarfile.open(archive, "r:gz") as tar:
            for member in tar:
                problem = _member_problem(member) or _through_link(temp, member.name)
                if problem:
                    raise TreeError(f"{Path(archive).name}: {problem}")
                target = temp / member.name
                if member.isdir():
                    target.mkdir(parents=True, exist_ok=True)
                elif member.issym():
                    target.parent.mkdir(parents=True, exist_ok=True)
                    os.symlink(member.linkname, target)
                elif member.isfile():
                    target.parent.mkdir(parents=True, exist_ok=True)
                    with tar.extractfile(member) as source, open(target, "xb") as sink:
                        while chunk := source.read(1 << 20):
                            sink.write(chunk)
                    os.chmod(target, 0o755 if member.mode & 0o111 else 0o644)
        problem = _link_leaving(temp)
        if problem:
            raise TreeError(f"{Path(archive).name}: {problem}")
        os.replace(temp, destination)
    except (tarfile.TarError, OSError, EOFError) as error:
        _remove(temp)
        raise TreeError(f"{Path(archive).name}: cannot unpack ({error})") from None
    except BaseException:
        _remove(temp)
        raise


def _remove(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)
