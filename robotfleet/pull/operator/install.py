"""What a push deploy sends a pull robot so that its agent can run: the
deploy tree of this checkout (as the operator runs it: the working tree's
tracked files), the wheels of the current release for the robot's platform
(the venv its releases run in) and the release repository's root.json.

Both are identified by content: the tree by robotfleet/pull/protocol/tree.py's hash
(a release names its code the same way), the wheel set by
``agent_files.venv_id``.  The robot keeps them under those names, so a converged
robot compares two names read in the deploy's one snapshot command.
"""

from __future__ import annotations

import functools
import gzip
import hashlib
import os
import stat
import subprocess
import tarfile
import tempfile
from pathlib import Path

from tuf.api.metadata import Metadata, Root

from robotfleet.pull.operator import channel
from robotfleet.pull.operator import keys as keyfiles
from robotfleet.pull.operator.repository import Repository, RepositoryError
from robotfleet.pull.protocol import agent_files, tree

_SKIPPED_PARTS = ("__pycache__",)
_SKIPPED_SUFFIXES = (".pyc", ".pyo")


class InstallError(Exception):
    """One line: what a push deploy cannot send a pull robot."""


def _tracked(checkout: Path) -> list[str] | None:
    """The deploy tree's files git tracks in ``checkout`` (None: not a git checkout)."""
    try:
        done = subprocess.run(
            ["git", "-C", str(checkout), "ls-files", "-z", "--", *tree.DEPLOY_PATHS], capture_output=True, timeout=60
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    if done.returncode != 0:
        return None
    return sorted({p.decode() for p in done.stdout.split(b"\0") if p})


def _walked(checkout: Path) -> list[str]:
    found = []
    for top in tree.DEPLOY_PATHS:
        path = checkout / top
        if path.is_file() or path.is_symlink():
            found.append(top)
            continue
        for directory, dirs, files in os.walk(path):
            dirs[:] = sorted(d for d in dirs if d not in _SKIPPED_PARTS and not d.endswith(".egg-info"))
            for name in sorted(files):
                if not name.endswith(_SKIPPED_SUFFIXES):
                    found.append(os.path.relpath(os.path.join(directory, name), checkout))
    return found


def deploy_files(checkout: Path) -> list[str]:
    """The files of the deploy tree as the operator runs it (tracked files
    of the working tree; every file when it is not a git checkout)."""
    tracked = _tracked(checkout)
    files = tracked if tracked is not None else _walked(checkout)
    return [f for f in files if os.path.lexists(checkout / f)]  # deleted, not yet committed


def _entry(checkout: Path, path: str) -> tree.Entry:
    full = checkout / path
    info = os.lstat(full)
    if stat.S_ISLNK(info.st_mode):
        return tree.Entry(path, tree.LINK, hashlib.sha256(os.fsencode(os.readlink(full))).hexdigest())
    mode = tree.EXECUTABLE if info.st_mode & 0o111 else tree.FILE
    return tree.Entry(path, mode, hashlib.sha256(full.read_bytes()).hexdigest())


@functools.lru_cache(maxsize=4)
def code_archive(checkout: Path) -> tuple[str, str]:
    """(the tree's hash, a tar.gz of it on this machine), made once per process."""
    files = deploy_files(checkout)
    if not files:
        raise InstallError(f"{checkout}: no deploy tree ({', '.join(tree.DEPLOY_PATHS)})")
    entries = [_entry(checkout, f) for f in files]
    fd, path = tempfile.mkstemp(prefix="robotfleet-code-", suffix=".tar.gz")
    with (
        os.fdopen(fd, "wb") as raw,
        gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0) as packed,
        tarfile.open(fileobj=packed, mode="w") as archive,
    ):
        for entry in sorted(entries):
            info = archive.gettarinfo(str(checkout / entry.path), arcname=entry.path)
            info.uid = info.gid = 0
            info.uname = info.gname = "root"
            info.mtime = 0
            info.mode = 0o755 if entry.mode == tree.EXECUTABLE else 0o644
            if info.isreg():
                with open(checkout / entry.path, "rb") as content:
                    archive.addfile(info, content)
            else:
                archive.addfile(info)
    return tree.tree_sha256(entries), path


def releases_clone(checkout: Path) -> Path:
    """Where robotfleet publish keeps its copy of the release repository."""
    return Path(os.environ.get(channel.CLONE_ENV) or checkout / ".robotfleet" / "releases")


def remote_ca(checkout: Path, setting: str | None) -> bytes | None:
    """The PEM CA file pull_remote_ca names (None: no setting); InstallError
    (one line) when it cannot be read or holds no certificate."""
    if not setting:
        return None
    path = checkout / setting
    try:
        data = path.read_bytes()
    except OSError:
        raise InstallError(f"pull_remote_ca: {path} cannot be read") from None
    if b"-----BEGIN CERTIFICATE-----" not in data:
        raise InstallError(f"pull_remote_ca: {path} holds no PEM certificate (-----BEGIN CERTIFICATE-----)")
    return data


def trust_root(checkout: Path, setting: str | None) -> bytes:
    """The root.json a push deploy gives a robot: the file the setting names,
    else the published repository's; it must be a TUF root signed by its own
    root keys, one of which is the operator's root.pub where the key
    directory has it.  InstallError (one line) otherwise."""
    path = checkout / setting if setting else releases_clone(checkout) / "metadata" / "root.json"
    try:
        data = path.read_bytes()
    except OSError:
        raise InstallError(
            f"pull_trust_root: {path} cannot be read; publish a first release "
            "(robotfleet keys init; robotfleet publish), docs/guides/pull.md"
        ) from None
    try:
        md = Metadata[Root].from_bytes(data)
        md.signed.verify_delegate(Root.type, md.signed_bytes, md.signatures)
    except Exception as error:  # every way a root can be bad is one refusal
        raise InstallError(
            f"pull_trust_root: {path} is not a TUF root signed by its own keys "
            f"({str(error).splitlines()[0] if str(error) else type(error).__name__})"
        ) from None
    known = _operator_root_keys()
    if known and not known & set(md.signed.roles[Root.type].keyids):
        raise InstallError(
            f"pull_trust_root: {path} is signed by none of the root keys in "
            f"{keyfiles.default_dir()} (root.pub): not this operator's repository"
        )
    return data


def _operator_root_keys() -> set[str]:
    found = set()
    for name in (keyfiles.ROOT, "root.next"):
        try:
            found.add(keyfiles.KeyDir().public(name).keyid)
        except (keyfiles.KeyProblem, OSError):
            continue
    return found


@functools.lru_cache(maxsize=16)
def wheel_set(clone: Path, platform: str) -> tuple[str, tuple[tuple[str, Path], ...]]:
    """(the venv id, ((wheel name, its file), ...)) of ``platform`` in the
    latest release of the repository in ``clone``: a push deploy gives a
    robot the venv its releases run in."""
    repository = Repository(clone)
    try:
        record = repository.record() if repository.exists() else None
        if record is None:
            raise InstallError(
                f"{clone}: no release published yet; the agent runs in the venv of the "
                "current release (robotfleet publish first)"
            )
        paths = record.wheels_for(platform)
        if not paths:
            raise InstallError(
                f"release {record.version} carries no wheels for {platform} (pull_platform); "
                f"publish again (robotfleet publish --platform {platform})"
            )
        targets = repository.targets().signed.targets
        files = tuple((path.rsplit("/", 1)[-1], repository.blob(path)) for path in paths)
    except RepositoryError as error:
        raise InstallError(str(error)) from None
    venv = agent_files.venv_id((name, targets[path].hashes["sha256"]) for (name, _), path in zip(files, paths))
    return venv, files


@functools.lru_cache(maxsize=16)
def wheels_archive(files: tuple[tuple[str, Path], ...]) -> str:
    """A tar of the wheels (flat, under their names) on this machine."""
    fd, path = tempfile.mkstemp(prefix="robotfleet-wheels-", suffix=".tar")
    with os.fdopen(fd, "wb") as raw, tarfile.open(fileobj=raw, mode="w") as archive:
        for name, stored in files:
            info = tarfile.TarInfo(name)
            info.size, info.mode, info.mtime = stored.stat().st_size, 0o644, 0
            with open(stored, "rb") as content:
                archive.addfile(info, content)
    return path


def read_probe(text: str) -> dict[str, str]:
    """The robot's current venv and code ids from ``PROBE`` (empty: none usable)."""
    found = {"venv": "", "code": ""}
    for line in text.splitlines():
        key, _, value = line.partition("=")
        if key in found:
            found[key] = value.strip().rsplit("/", 1)[-1]
    return found


# Each link's target, when what it points at is usable.
PROBE = (
    f"v=$(readlink {agent_files.VENV}); [ -x {agent_files.VENV}/bin/python ] || v=; echo venv=$v; "
    f"c=$(readlink {agent_files.CURRENT_CODE}); [ -f {agent_files.CURRENT_CODE}/deploy.py ] || c=; echo code=$c"
)


def venv_script(venv: str) -> str:
    """Unpack the wheels (a tar on stdin, base64) and make venv ``venv`` from
    them beside the current one, then switch; the previous one is kept."""
    return f"""set -e
umask 077
state={agent_files.STATE}; id={venv}
mkdir -p "$state/wheels" "$state/venvs"
tmp=$(mktemp -d "$state/.install.XXXXXX"); trap 'rm -rf "$tmp"' EXIT
base64 -d | tar -x -C "$tmp" --no-same-owner
rm -rf "$state/wheels/$id" "$state/venvs/$id"
mv -T "$tmp" "$state/wheels/$id"
mkdir "$tmp"
python3 -m venv "$tmp/venv"
"$tmp/venv/bin/python" -m pip install -q --no-index --no-deps --disable-pip-version-check "$state/wheels/$id"/*.whl
mv -T "$tmp/venv" "$state/venvs/$id"
old=$(readlink "$state/venv" || true)
ln -sfn "venvs/$id" "$state/.venv.new" && mv -T "$state/.venv.new" "$state/venv"
for d in "$state"/venvs/* "$state"/wheels/*; do
  case "${{d##*/}}" in "$id"|"${{old##*/}}") ;; *) rm -rf "$d" ;; esac
done
"""


def code_script(code: str) -> str:
    """Unpack the deploy tree (a tar.gz on stdin, base64) as ``code`` and make it current."""
    return f"""set -e
umask 022
dir={agent_files.CODE}; id={code}
mkdir -p "$dir"
tmp=$(mktemp -d "$dir/.install.XXXXXX"); trap 'rm -rf "$tmp"' EXIT
base64 -d | tar -xz -C "$tmp" --no-same-owner
chmod 0755 "$tmp"
rm -rf "$dir/$id"
mv -T "$tmp" "$dir/$id"
old=$(readlink "$dir/current" || true)
ln -sfn "$id" "$dir/.current.new" && mv -T "$dir/.current.new" "$dir/current"
for d in "$dir"/*; do
  case "${{d##*/}}" in current|"$id"|"$old") ;; *) rm -rf "$d" ;; esac
done
"""
