"""The operator's TUF repository, in a directory (a checkout of the fleet
remote's robotfleet/releases branch, or one served over static HTTPS):

    metadata/root.json  metadata/N.root.json      the root, each version kept
    metadata/timestamp.json                       short-lived, re-signed by every publish
    metadata/N.snapshot.json  metadata/N.targets.json   (consistent snapshots)
    targets/release.json's blob: targets/<sha256>.release.json
    targets/code/<sha256>.<commit>.tar.gz, targets/wheels/<sha256>.<file>.whl

Two keys (robotfleet/pull/operator/keys.py): the root key signs only roots; the
online key signs targets, snapshot and timestamp (a root changed by hand:
robotfleet/pull/operator/root_ceremony.py).  Each publish writes the
target blobs first and timestamp.json last (one rename), so an HTTPS reader
never sees a timestamp naming files not yet there.  The last KEEP versions
of snapshot and targets and the blobs they name are kept; older ones go
(a git branch keeps them in its history anyway).
"""

from __future__ import annotations

import datetime
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from tuf.api.metadata import Metadata, MetaFile, Root, Snapshot, TargetFile, Targets, Timestamp
from tuf.api.serialization.json import JSONSerializer

from robotfleet import atomicfile
from robotfleet.pull.protocol import record as records

ONLINE_ROLES = (Targets.type, Snapshot.type, Timestamp.type)
KEEP = 3
SERIALIZER = JSONSerializer(compact=False)
_DURATION = re.compile(r"([1-9][0-9]{0,4})([mhdw])")
_UNITS = {"m": 60, "h": 3600, "d": 86400, "w": 7 * 86400}


class RepositoryError(Exception):
    """The repository cannot do what was asked; the message is one line."""


def parse_duration(text, option: str) -> datetime.timedelta:
    """'12h', '7d', '4w', '90m' -> timedelta; ValueError naming ``option``."""
    match = _DURATION.fullmatch(str(text).strip())
    if not match:
        raise ValueError(f"{option}: expected a duration like 90m, 12h, 7d or 4w, got {text!r}")
    return datetime.timedelta(seconds=int(match.group(1)) * _UNITS[match.group(2)])


@dataclass(frozen=True)
class Expiry:
    """How long each role's metadata stays valid after it is signed.  The
    timestamp is short (a withheld release shows within days); robots stop
    accepting anything once it passes, so `robotfleet publish --renew` runs
    more often than that (a daily timer)."""

    timestamp: datetime.timedelta = datetime.timedelta(days=7)
    snapshot: datetime.timedelta = datetime.timedelta(days=30)
    targets: datetime.timedelta = datetime.timedelta(days=30)
    root: datetime.timedelta = datetime.timedelta(days=365)


def expires(now: datetime.datetime, period: datetime.timedelta) -> datetime.datetime:
    return (now + period).astimezone(datetime.timezone.utc).replace(microsecond=0)


def blob_name(path: str, sha256: str) -> str:
    """Where target ``path`` is stored under targets/ (python-tuf's consistent-snapshot name)."""
    directory, _, name = path.rpartition("/")
    return f"{directory}/{sha256}.{name}" if directory else f"{sha256}.{name}"


def _write(path: Path, data: bytes) -> None:
    atomicfile.write(path, data, mode=0o644, make_parents=True)


class Repository:
    """The TUF repository in ``path`` (see the module's docstring)."""

    def __init__(self, path):
        self.path = Path(path)
        self.metadata = self.path / "metadata"
        self.targets_dir = self.path / "targets"

    def exists(self) -> bool:
        return (self.metadata / "root.json").is_file()

    # reading -------------------------------------------------------------

    def root(self) -> Metadata[Root]:
        return self._load("root.json", Root)

    def timestamp(self) -> Metadata[Timestamp]:
        return self._load("timestamp.json", Timestamp)

    def snapshot(self) -> Metadata[Snapshot]:
        return self._load(f"{self.timestamp().signed.snapshot_meta.version}.snapshot.json", Snapshot)

    def targets(self) -> Metadata[Targets]:
        return self._load(f"{self.snapshot().signed.meta['targets.json'].version}.targets.json", Targets)

    def _load(self, name: str, kind) -> Metadata:
        path = self.metadata / name
        try:
            md = Metadata.from_file(str(path))
        except FileNotFoundError:
            raise RepositoryError(f"{path}: missing (not a robotfleet release repository?)") from None
        except Exception as error:  # any unreadable metadata is one line
            raise RepositoryError(f"{path}: unreadable TUF metadata ({str(error).splitlines()[0]})") from None
        if md.signed.type != kind.type:
            raise RepositoryError(f"{path}: {md.signed.type} metadata where {kind.type} was expected")
        return md

    def blob(self, path: str) -> Path:
        """The stored file of target ``path`` (checked against its signed length and hash)."""
        info = self.targets().signed.targets.get(path)
        if info is None:
            raise RepositoryError(f"{path}: not a target of the current release")
        stored = self.targets_dir / blob_name(path, info.hashes["sha256"])
        try:
            with open(stored, "rb") as handle:
                info.verify_length_and_hashes(handle)
        except FileNotFoundError:
            raise RepositoryError(f"{stored}: missing from the repository") from None
        except Exception as error:
            raise RepositoryError(f"{stored}: differs from what was signed ({error})") from None
        return stored

    def record(self) -> records.Record | None:
        """The current release record (None before the first release)."""
        if records.NAME not in self.targets().signed.targets:
            return None
        try:
            return records.parse(self.blob(records.NAME).read_bytes())
        except records.RecordError as error:
            raise RepositoryError(str(error)) from None

    # writing -------------------------------------------------------------

    def create(self, root_signer, online_signer, expiry: Expiry, now: datetime.datetime) -> None:
        """A new repository: root v1 (root key for root, the online key for
        the other roles), signed by the root key; empty targets, snapshot
        and timestamp signed by the online key.  Refuses an existing one."""
        if self.exists():
            raise RepositoryError(f"{self.metadata / 'root.json'}: a repository is already there")
        root = Metadata(Root(expires=expires(now, expiry.root), consistent_snapshot=True))
        root.signed.add_key(root_signer.public_key, Root.type)
        for role in ONLINE_ROLES:
            root.signed.add_key(online_signer.public_key, role)
        root.sign(root_signer)
        self.write_root(root.to_bytes(SERIALIZER), 1)
        targets = Metadata(Targets(version=1, expires=expires(now, expiry.targets)))
        self._publish_targets(targets, online_signer, expiry, now, first=True)

    def write_root(self, data: bytes, version: int) -> None:
        _write(self.metadata / f"{version}.root.json", data)
        _write(self.metadata / "root.json", data)

    def _store(self, path: str, local: Path) -> TargetFile:
        info = TargetFile.from_file(path, str(local), ["sha256"])
        stored = self.targets_dir / blob_name(path, info.hashes["sha256"])
        if not stored.exists():
            with open(local, "rb") as source, atomicfile.replacing(stored, 0o644, make_parents=True) as copy:
                shutil.copyfileobj(source, copy)
        return info

    def publish(
        self, record: records.Record, files: dict[str, Path], online_signer, expiry: Expiry, now: datetime.datetime
    ) -> None:
        """Make ``record`` the current release: release.json and ``files``
        (target path -> local file: exactly the record's code and wheels)
        become the targets; targets, snapshot and timestamp get their next
        versions and new expiries, signed by ``online_signer``."""
        wanted, given = set(record.targets()), set(files)
        if wanted != given:
            missing = sorted(wanted - given) or sorted(given - wanted)
            raise RepositoryError(f"{missing[0]}: the record's targets and the files given differ")
        current = self.record() if self.exists() else None
        if current is not None and record.version <= current.version:
            raise RepositoryError(f"release {record.version}: not above the current release {current.version}")
        with tempfile.TemporaryDirectory() as scratch:
            release = Path(scratch, records.NAME)
            release.write_bytes(record.to_bytes())
            chosen = {records.NAME: self._store(records.NAME, release)}
            chosen.update({path: self._store(path, Path(local)) for path, local in sorted(files.items())})
        targets = self.targets()
        targets.signed.targets = chosen
        self._publish_targets(targets, online_signer, expiry, now)

    def extend(
        self,
        files: dict[str, Path],
        online_signer,
        expiry: Expiry,
        now: datetime.datetime,
        elsewhere=None,
        replacing=(),
    ) -> None:
        """The current release with more targets (``files``: target path ->
        local file; a release on media adds its image index and archives):
        the same record, targets, snapshot and timestamp at their next
        versions.  Files whose path is in ``elsewhere`` are signed but not
        stored here (image archives live on the media, never on the releases
        branch: robotfleet/pull/operator/export.py copies them there);
        targets in ``replacing`` (an earlier export's) are dropped first."""
        elsewhere = set(elsewhere or ())
        targets = self.targets()
        for path in replacing:
            targets.signed.targets.pop(path, None)
        taken = sorted(set(files) & set(targets.signed.targets))
        if taken:
            raise RepositoryError(f"{taken[0]}: already a target of the current release")
        for path, local in sorted(files.items()):
            if path in elsewhere:
                targets.signed.targets[path] = TargetFile.from_file(path, str(local), ["sha256"])
            else:
                targets.signed.targets[path] = self._store(path, Path(local))
        self._publish_targets(targets, online_signer, expiry, now)

    def _publish_targets(
        self, targets: Metadata[Targets], online_signer, expiry: Expiry, now: datetime.datetime, first: bool = False
    ) -> None:
        """Sign and write ``targets`` at its next version (``first``: as is,
        version 1, with snapshot and timestamp version 1), then a snapshot and
        a timestamp naming it."""
        self._check_online(online_signer)
        targets.signed.version += 0 if first else 1
        targets.signed.expires = expires(now, expiry.targets)
        targets.sign(online_signer)
        data = targets.to_bytes(SERIALIZER)
        _write(self.metadata / f"{targets.signed.version}.targets.json", data)
        snapshot = Metadata(Snapshot(version=1 if first else self.snapshot().signed.version))
        snapshot.signed.meta["targets.json"] = MetaFile.from_data(targets.signed.version, data, ["sha256"])
        self._publish_snapshot(snapshot, online_signer, expiry, now, first)
        self._prune()

    def _publish_snapshot(
        self, snapshot: Metadata[Snapshot], online_signer, expiry: Expiry, now: datetime.datetime, first: bool = False
    ) -> None:
        snapshot.signed.version += 0 if first else 1
        snapshot.signed.expires = expires(now, expiry.snapshot)
        snapshot.sign(online_signer)
        data = snapshot.to_bytes(SERIALIZER)
        _write(self.metadata / f"{snapshot.signed.version}.snapshot.json", data)
        version = 0 if first else self.timestamp().signed.version
        self._publish_timestamp(
            version, MetaFile.from_data(snapshot.signed.version, data, ["sha256"]), online_signer, expiry, now
        )

    def _publish_timestamp(
        self, previous: int, snapshot_meta: MetaFile, online_signer, expiry: Expiry, now: datetime.datetime
    ) -> None:
        timestamp = Metadata(
            Timestamp(version=previous + 1, expires=expires(now, expiry.timestamp), snapshot_meta=snapshot_meta)
        )
        timestamp.sign(online_signer)
        _write(self.metadata / "timestamp.json", timestamp.to_bytes(SERIALIZER))

    def _check_online(self, signer) -> None:
        """Refuse to sign with a key the root does not name (robots would refuse it as unknown)."""
        named = self.root().signed.roles[Timestamp.type].keyids
        if signer.public_key.keyid not in named:
            raise RepositoryError(
                f"the online key here ({signer.public_key.keyid[:16]}) is not the one the "
                f"repository's root names ({', '.join(k[:16] for k in named)}): "
                "was it rotated on another machine?"
            )

    def renew(self, online_signer, expiry: Expiry, now: datetime.datetime) -> list[str]:
        """Re-sign what expires before the next timestamp would: always the
        timestamp, the snapshot (and targets) when due.  The names re-signed.
        A due targets role is re-signed as is: its release.json keeps its own
        expiry, so a release near its record's expiry needs a new publish."""
        due = expires(now, expiry.timestamp)
        targets, snapshot = self.targets(), self.snapshot()
        if targets.signed.expires <= due:
            self._publish_targets(targets, online_signer, expiry, now)
            return list(ONLINE_ROLES)
        if snapshot.signed.expires <= due:
            self._publish_snapshot(snapshot, online_signer, expiry, now)
            return [Snapshot.type, Timestamp.type]
        self._check_online(online_signer)
        self._publish_timestamp(
            self.timestamp().signed.version, self.timestamp().signed.snapshot_meta, online_signer, expiry, now
        )
        return [Timestamp.type]

    def resign(self, online_signer, expiry: Expiry, now: datetime.datetime) -> None:
        """Targets, snapshot and timestamp re-signed at their next versions
        (after a root change names another online key)."""
        self._publish_targets(self.targets(), online_signer, expiry, now)

    def _prune(self) -> None:
        """Keep the newest KEEP snapshot and targets versions and the target blobs they name."""
        kept_targets: set[Path] = set()
        for role in (Snapshot.type, Targets.type):
            versions = sorted(
                int(p.name.split(".")[0])
                for p in self.metadata.glob(f"*.{role}.json")
                if p.name.split(".")[0].isdigit()
            )
            for version in versions[:-KEEP]:
                (self.metadata / f"{version}.{role}.json").unlink()
            if role == Targets.type:
                for version in versions[-KEEP:]:
                    md = Metadata.from_file(str(self.metadata / f"{version}.{role}.json"))
                    kept_targets |= {
                        self.targets_dir / blob_name(p, i.hashes["sha256"]) for p, i in md.signed.targets.items()
                    }
        for stored in self.targets_dir.rglob("*") if self.targets_dir.exists() else ():
            if stored.is_file() and stored not in kept_targets:
                stored.unlink()
