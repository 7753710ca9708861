"""A release on removable media or a LAN share (``robotfleet export DIR``).

The current release of the fleet's repository is re-signed with more TUF
targets: ``media.json`` (robotfleet/pull/protocol/media.py) and an archive
of each image a robot of the release runs, for that robot's machine, each
written by the role that pins it (robotfleet/role.py PinPart ``archive``;
the payload role reads them from their registries).  The record stays the
same release: robots that already applied it do nothing.  The re-signed
metadata goes back where the release is published (the releases branch, or
the --to-dir directory), so the media and the network never disagree on a
version; the archives are stored on the media only (robots fetching the
branch never download them).  Then DIR gets the whole repository: metadata,
the code, the wheels and the archives, every file checked against what was
signed on the way, the timestamp written last.
"""

from __future__ import annotations

import datetime
import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

from robotfleet.fleet import pull_mode
from robotfleet.pull.operator import publishing
from robotfleet.pull.operator.medium import METADATA_NAME, Medium, MediumError
from robotfleet.pull.operator.repository import Expiry, Repository, RepositoryError, blob_name
from robotfleet.pull.protocol import media, platforms


class ExportError(Exception):
    """Nothing was exported; the message is one line."""


@dataclass(frozen=True)
class Exported:
    version: int
    images: int  # archives written (one per image and machine)
    size: int  # their bytes
    robots: int


def archives(record, hosts: dict, roles, work: Path) -> tuple[dict, dict[str, Path]]:
    """The media index's images and the archive files: ({machine: {ref:
    entry}}, {target path: file}), each image and machine once."""
    index: dict[str, dict[str, dict[str, str]]] = {}
    files: dict[str, Path] = {}
    for robot in record.robots:
        data = hosts.get(robot)
        if data is None:
            raise ExportError(f"{robot}: in release {record.version} but not a pull host of its fleet file")
        machine = platforms.parse_platform(pull_mode.value(data, "pull_platform"))[1]
        pins = record.images_of(robot)
        for role in roles:
            if role.pins is None or not role.runs_on(data):
                continue
            for ref in dict.fromkeys(role.pins.refs(data)):
                if ref not in pins or ref in index.get(machine, {}):
                    continue
                if role.pins.archive is None:
                    raise ExportError(f"{robot}: {role.name} pins {ref} but cannot write it to media")
                name = hashlib.sha256(f"{ref}@{pins[ref]}".encode()).hexdigest()[:24]
                path = media.archive_path(name, machine)
                local = work / path
                local.parent.mkdir(parents=True, exist_ok=True)
                try:
                    image = role.pins.archive(data, ref, pins[ref], machine, local)
                except ValueError as error:
                    raise ExportError(f"{robot}: {role.name}: {error}") from None
                index.setdefault(machine, {})[ref] = {"digest": pins[ref], "archive": path, "image": image}
                files[path] = local
    return index, files


def copy_out(repository: Repository, medium, extra: dict[str, Path] | None = None) -> None:
    """Every file of ``repository``'s current release into ``medium`` (a
    directory, or a Medium already open: robotfleet/pull/operator/medium.py,
    no link under it followed, only the names an export writes replaced or
    deleted), each blob checked against what was signed (one already there
    is kept only when its bytes are the signed ones), the metadata after
    them and the timestamp last; what the medium held of older exports is
    pruned.  ``extra``: target path -> local file, for the blobs stored
    nowhere else (an export's image archives)."""
    if not isinstance(medium, Medium):
        with Medium(getattr(medium, "path", medium)) as out:
            return copy_out(repository, out, extra)
    extra = extra or {}
    kept = set()
    for path, info in repository.targets().signed.targets.items():
        stored = f"targets/{blob_name(path, info.hashes['sha256'])}"
        kept.add(stored)
        if medium.has(stored, info.length, info.hashes["sha256"]):
            continue
        source = Path(extra[path]) if path in extra else repository.targets_dir / stored.removeprefix("targets/")
        try:
            with open(source, "rb") as handle:
                medium.write(stored, handle, info.length, info.hashes["sha256"])
        except FileNotFoundError:
            raise ExportError(f"{source}: missing from the repository") from None
    names = sorted(
        p.name
        for p in repository.metadata.iterdir()
        if p.is_file() and METADATA_NAME.match(p.name) and p.name != "timestamp.json"
    )
    for name in names + ["timestamp.json"]:
        medium.write(f"metadata/{name}", (repository.metadata / name).read_bytes())
    medium.prune("targets", kept)
    medium.prune("metadata", {f"metadata/{name}" for name in names + ["timestamp.json"]})


def export(
    repository: Repository,
    medium: Path,
    checkout,
    roles,
    registry,
    signer,
    expiry: Expiry,
    now: datetime.datetime,
    work: Path,
) -> Exported:
    """Re-sign ``repository``'s current release with its image archives
    (stored in ``medium`` only) and write the whole of it into ``medium``."""
    try:
        record = repository.record() if repository.exists() else None
    except RepositoryError as error:
        raise ExportError(str(error)) from None
    if record is None:
        raise ExportError(f"{repository.path}: no release to export (publish one first)")
    if record.halt:
        raise ExportError(f"release {record.version} is a halt ({record.halt_reason}): nothing to export")
    if medium.resolve() == repository.path.resolve():
        raise ExportError(f"{medium}: the media directory is the published repository itself")
    try:
        with Medium(medium):  # refused before anything is read, signed or written
            pass
    except MediumError as error:
        raise ExportError(str(error)) from None
    try:
        fleet, _ = publishing.read_fleet(checkout, record.commit, record.fleet["path"], registry)
    except publishing.PublishError as error:
        raise ExportError(str(error).splitlines()[-1]) from None
    refused = publishing.secret_refusal(fleet, record.fleet["path"])
    if refused:
        raise ExportError(f"{refused}; nothing was exported")
    hosts = dict(publishing.pull_hosts(fleet, registry))
    index, files = archives(record, hosts, roles, work)
    (work / media.NAME).write_bytes(media.build(record.version, index))
    current = repository.targets().signed.targets
    old = [path for path in current if path == media.NAME or path.startswith("images/")]
    try:  # an earlier export of this release: its index and archives are replaced
        repository.extend(
            {media.NAME: work / media.NAME, **files},
            signer,
            expiry,
            now,
            elsewhere=set(files),
            replacing=old,
        )
    except RepositoryError as error:
        raise ExportError(str(error)) from None
    try:
        copy_out(repository, medium, files)
    except MediumError as error:
        raise ExportError(str(error)) from None
    return Exported(record.version, len(files), sum(os.path.getsize(f) for f in files.values()), len(record.robots))
