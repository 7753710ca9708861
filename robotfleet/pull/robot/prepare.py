"""Putting a verified release in place on the robot, before the lock is
taken: its deploy tree under ``code/<tree hash>`` (checked against the
record's hash after unpacking, and the fleet file against its own), and a
venv made from its wheels under ``venvs/<id>``.  Nothing here changes what
the robot runs: the agent switches ``code/current`` and ``venv`` only once
the release applied."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from robotfleet.pull.protocol import agent_files, tree

VENV_TIMEOUT = 900


class Mismatch(Exception):
    """The unpacked release is not what the record binds (one line)."""


class PrepareError(Exception):
    """The release cannot be put in place here (one line)."""


def code_dir(state: Path, record, archive: Path) -> Path:
    """The release's deploy tree, unpacked once and checked: its content hash
    must be the record's, and its fleet file's hash too (Mismatch)."""
    target = state / "code" / record.tree_sha256
    if not target.is_dir():
        (state / "code").mkdir(parents=True, exist_ok=True)
        try:
            tree.unpack(archive, target)
        except tree.TreeError as error:
            raise Mismatch(str(error)) from None
    found = tree.tree_sha256(tree.entries_of_directory(target))
    if found != record.tree_sha256:
        shutil.rmtree(target, ignore_errors=True)
        raise Mismatch(f"the code archive's tree hashes to {found[:12]}, the record binds {record.tree_sha256[:12]}")
    fleet = target / record.fleet["path"]
    try:
        digest = hashlib.sha256(fleet.read_bytes()).hexdigest()
    except OSError:
        raise Mismatch(f"the release's tree has no {record.fleet['path']}") from None
    if digest != record.fleet["sha256"]:
        raise Mismatch(
            f"{record.fleet['path']} hashes to {digest[:12]}, the record binds {record.fleet['sha256'][:12]}"
        )
    return target


def venv_for(state: Path, wheels: dict[str, Path], python: str = "/usr/bin/python3") -> Path:
    """The venv made from ``wheels`` (target path -> verified file), made
    beside the others if it is not there yet; its directory."""
    venv = agent_files.venv_id((path.rsplit("/", 1)[-1], _sha256(file)) for path, file in wheels.items())
    target = state / "venvs" / venv
    if (target / "bin" / "python").exists():
        return target
    (state / "venvs").mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(dir=state / "venvs", prefix=f".{venv}."))
    try:
        flat = work / "wheels"
        flat.mkdir()
        for path, file in wheels.items():
            os.link(file, flat / path.rsplit("/", 1)[-1]) if _same_fs(file, flat) else shutil.copy(file, flat)
        _run([python, "-m", "venv", str(work / "venv")], "python3 -m venv")
        _run(
            [
                str(work / "venv" / "bin" / "python"),
                "-m",
                "pip",
                "install",
                "--quiet",
                "--no-index",
                "--no-deps",
                "--disable-pip-version-check",
                *sorted(str(p) for p in flat.iterdir()),
            ],
            "pip install",
        )
        os.replace(work / "venv", target)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return target


def switch(link: Path, target: Path) -> None:
    """Point ``link`` at ``target`` (relative, one rename)."""
    temp = link.with_name(f".{link.name}.new")
    if temp.is_symlink() or temp.exists():
        temp.unlink()
    os.symlink(os.path.relpath(target, link.parent), temp)
    os.replace(temp, link)


def prune(directory: Path, keep: set[Path]) -> None:
    """Remove what ``directory`` holds beside ``keep`` (the current and the
    previous release's trees or venvs)."""
    if not directory.is_dir():
        return
    kept = {p.resolve() for p in keep if p.exists()}
    for entry in directory.iterdir():
        if entry.is_symlink() or entry.resolve() in kept:
            continue
        shutil.rmtree(entry, ignore_errors=True) if entry.is_dir() else entry.unlink(missing_ok=True)


def prune_targets(directory: Path, keep: set[Path]) -> None:
    """Remove downloaded targets other than ``keep`` (the applied release's)."""
    kept = {p.resolve() for p in keep}
    for path in directory.rglob("*") if directory.is_dir() else ():
        if path.is_file() and path.resolve() not in kept:
            path.unlink(missing_ok=True)


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while chunk := handle.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def _same_fs(a: Path, b: Path) -> bool:
    return os.stat(a).st_dev == os.stat(b).st_dev


def _run(command: list[str], what: str) -> None:
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=VENV_TIMEOUT)
    except (OSError, subprocess.TimeoutExpired) as error:
        raise PrepareError(f"{what}: {error}") from None
    if done.returncode:
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        raise PrepareError(f"{what}: {lines[-1].strip() if lines else f'exit {done.returncode}'}")
