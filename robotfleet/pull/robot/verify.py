"""The robot's side of a release's trust: a verified refresh of the TUF
repository the operator published (python-tuf's ngclient), from a local
directory (the fetched copy of the releases branch) or an HTTP(S) base URL.

A robot's trust state lives in one directory (the agent's, root-only):

    <state>/tuf          -> tuf-<random>/   the trusted metadata (ngclient's cache:
                                            root.json, root_history/, timestamp, snapshot, targets)
    <state>/trust.json   {"format": 1, "time": "...Z", "version": N, "release": "..."}

``time`` is the last trusted time: the newest of the clock at a successful
check and the ``published`` time of the newest record accepted.  Expiry is
checked against max(system clock, last trusted time), so a robot that boots
in 1970 (no RTC) still verifies, and a clock behind what it already trusted
is never believed.  ``version`` is the highest record version accepted: a
record below it (or below the version the agent applied) is a rollback.

A refresh works on a copy of the trusted metadata and swaps it in (one
rename of the ``tuf`` link) only when everything verified: a refusal leaves
the trusted state as it was.  Every refusal is a Refused with one line and
a reason from REASONS (robotfleet/pull/robot/refusals.py).  Nothing here needs the operator's keys.
"""

from __future__ import annotations

import datetime
import os
import secrets
import shutil
import tempfile
from pathlib import Path
from urllib import parse

from tuf.api import exceptions
from tuf.api.metadata import Metadata, Root
from tuf.ngclient import FetcherInterface, Updater, UpdaterConfig

from robotfleet.pull.protocol import record as records
from robotfleet.pull.robot import fetched, trust_state, tufprivate
from robotfleet.pull.robot.refusals import (
    EXPIRED,
    MALFORMED,
    ROLLBACK,
    WORDS,
    Refused,
    classified,
    first_line,
    unsigned_reason,
)
from robotfleet.pull.robot.trust_state import EPOCH, State


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc)


def read_state(state_dir) -> State:
    """The trust state kept in ``state_dir`` (defaults if it has none yet)."""
    try:
        return trust_state.read_state(state_dir)
    except trust_state.Unreadable as error:
        raise Refused(MALFORMED, str(error)) from None


def initialize(state_dir, root: bytes, trusted_time: datetime.datetime | None = None) -> None:
    """Make ``state_dir`` trust ``root`` (the fleet's root.json, e.g. from a
    first-boot bundle), with ``trusted_time`` as the last trusted time (the
    bundle's release's published time).  Refused(MALFORMED) if ``root`` is
    not a root signed by its own keys.  Replaces any earlier trust."""
    try:
        md = Metadata[Root].from_bytes(root)
        if not isinstance(md.signed, Root):
            raise ValueError("not a root")
        md.signed.verify_delegate(Root.type, md.signed_bytes, md.signatures)
    except Exception as error:  # every way a root can be bad is one refusal
        raise Refused(MALFORMED, f"trust root: not a self-signed TUF root ({first_line(error)})") from None
    state_dir = Path(state_dir)
    state_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
    fresh = Path(tempfile.mkdtemp(dir=state_dir, prefix="tuf-"))
    (fresh / "root_history").mkdir()
    (fresh / "root_history" / f"{md.signed.version}.root.json").write_bytes(root)
    os.symlink(f"root_history/{md.signed.version}.root.json", fresh / "root.json")
    _swap_in(state_dir, fresh)
    trust_state.write_state(state_dir, State(trusted_time or EPOCH, 0, None))


def _swap_in(state_dir: Path, fresh: Path) -> None:
    """Point <state>/tuf at ``fresh`` in one rename; remove what it pointed at."""
    link = state_dir / "tuf"
    old = os.path.realpath(link) if os.path.islink(link) else None
    temp_link = state_dir / f".tuf-link-{secrets.token_hex(4)}"
    os.symlink(fresh.name, temp_link)
    os.replace(temp_link, link)
    if old and Path(old) != fresh.resolve():
        shutil.rmtree(old, ignore_errors=True)


def _sweep(state_dir: Path) -> None:
    """Remove what an interrupted refresh left (work copies, a link not yet
    renamed); the agent's lock on its state directory keeps refreshes apart."""
    current = os.path.realpath(state_dir / "tuf")
    for entry in state_dir.iterdir():
        if entry.name.startswith(".tuf-link-"):
            entry.unlink(missing_ok=True)
        elif entry.name.startswith("tuf-") and str(entry.resolve()) != current:
            shutil.rmtree(entry, ignore_errors=True)


class DirectoryFetcher(FetcherInterface):
    """Reads ``file://`` URLs under one directory (the fetched releases
    branch), never through a link and only regular files
    (robotfleet/pull/robot/fetched.py), in chunks (ngclient stops at the cap of
    each file); anything missing or outside it answers like an HTTP 404."""

    def __init__(self, base):
        self.base = Path(base).resolve()

    def _fetch(self, url: str):
        parts = parse.urlsplit(url)
        path = Path(parse.unquote(parts.path))
        if parts.scheme != "file" or self.base not in path.parents or ".." in path.parts:
            raise exceptions.DownloadHTTPError(f"{url}: no such file", 404)
        relative = path.relative_to(self.base).as_posix()
        try:
            fd = fetched.open_file(self.base, relative)
        except FileNotFoundError:
            raise exceptions.DownloadHTTPError(f"{url}: no such file", 404) from None
        return fetched.chunks(fd, where=f"{self.base}/{relative}")


class _Recording(FetcherInterface):
    """The fetcher in use, keeping the last metadata file it read whole (to
    say whether a signature failed for want of one, an unknown key or a
    change); chunks pass as they come, so ngclient's caps hold."""

    def __init__(self, inner: FetcherInterface):
        self.inner = inner
        self.last: bytes | None = None

    def _fetch(self, url: str):
        chunks = self.inner.fetch(url)
        return self._kept(chunks) if "/metadata/" in url else chunks

    def _kept(self, chunks):
        kept = []
        for chunk in chunks:
            kept.append(chunk)
            yield chunk
        self.last = b"".join(kept)


def _config() -> UpdaterConfig:
    """ngclient's settings; a metadata file's cap is the one the cheap check reads by (fetched.py)."""
    return UpdaterConfig(
        app_user_agent="robotfleet",
        root_max_length=fetched.ROOT_MAX,
        timestamp_max_length=fetched.TIMESTAMP_MAX,
        snapshot_max_length=fetched.SNAPSHOT_MAX,
        targets_max_length=fetched.TARGETS_MAX,
    )


class Client:
    """A robot's verified view of the fleet's releases.

    ``source``: a directory holding the repository (``metadata/``,
    ``targets/``: the fetched releases branch) or an http(s):// base URL of
    the same two directories.  ``clock``: the system clock (tests pass
    another).  One Client does one refresh (python-tuf's rule)."""

    def __init__(self, state_dir, source: str, clock=_now):
        self.state_dir = Path(state_dir)
        self.source = str(source)
        self.clock = clock
        self.updater: Updater | None = None
        self.record: records.Record | None = None
        self.reference_time: datetime.datetime | None = None

    def _bases(self) -> tuple[str, str, FetcherInterface | None]:
        if self.source.startswith(("https://", "http://")):
            base = self.source.rstrip("/") + "/"
            return base + "metadata/", base + "targets/", None
        base = Path(self.source).resolve()
        url = "file://" + parse.quote(str(base))
        return url + "/metadata/", url + "/targets/", DirectoryFetcher(base)

    def refresh(self, applied: int = 0) -> records.Record:
        """Verify the repository and return its release record; refuse
        (Refused) anything unsigned, signed by an unknown key, tampered,
        below version max(``applied``, the highest accepted), expired, or
        malformed, leaving the trusted state untouched.  On success the new
        metadata and trust.json are kept."""
        self._check_root()
        _sweep(self.state_dir)
        self.trial(applied)
        return self.keep()

    def trial(self, applied: int = 0) -> records.Record:
        """refresh() without keeping anything yet: keep() or discard() next
        (``newest`` tries two sources from the same trusted state)."""
        self._check_root()
        state = read_state(self.state_dir)
        now = self.clock()
        self.reference_time = max(now, state.time)
        work = Path(tempfile.mkdtemp(dir=self.state_dir, prefix="tuf-"))
        try:
            shutil.copytree(self.state_dir / "tuf", work, symlinks=True, dirs_exist_ok=True)
            metadata_url, targets_url, fetcher = self._bases()
            recording = _Recording(fetcher or _https_fetcher())
            try:
                updater = Updater(str(work), metadata_url, None, targets_url, recording, _config(), bootstrap=None)
                tufprivate.set_reference_time(updater, self.reference_time)
                updater.refresh()
                raw = self._release_bytes(updater, work)
            except exceptions.UnsignedMetadataError as error:
                reason, role = unsigned_reason(recording.last, work)
                raise Refused(reason, f"{role}.json: {WORDS[reason]} ({first_line(error)})") from None
            except Refused:
                raise
            except Exception as error:  # classified below, never let through
                refused = classified(error)
                raise Refused(refused.reason, f"releases at {self.source}: {refused.line}") from None
            try:
                found = records.parse(raw)
            except records.RecordError as error:
                raise Refused(MALFORMED, str(error)) from None
            floor = max(applied, state.version)
            if found.version < floor:
                raise Refused(
                    ROLLBACK,
                    f"release {found.version} ({found.release}) is older than release {floor} "
                    "already accepted: refused as a rollback",
                )
            if found.expires_at <= self.reference_time:
                raise Refused(
                    EXPIRED,
                    f"release {found.version} ({found.release}) expired at {found.expires} "
                    f"(trusted time {records.utc(self.reference_time)}): refused as a freeze",
                )
        except BaseException:
            shutil.rmtree(work, ignore_errors=True)
            raise
        self.updater, self.record = updater, found
        self._tried = (work, state, now)
        return found

    def _check_root(self) -> None:
        if not (self.state_dir / "tuf" / "root.json").exists():
            raise Refused(MALFORMED, f"{self.state_dir}: no trusted root (initialize the robot's trust first)")

    def keep(self) -> records.Record:
        """What trial() verified becomes the trusted state."""
        work, state, now = self._tried
        found = self.record
        _swap_in(self.state_dir, work)
        trust_state.write_state(
            self.state_dir,
            State(max(state.time, now, found.published_at), max(state.version, found.version), found.release),
        )
        return found

    def discard(self) -> None:
        shutil.rmtree(self._tried[0], ignore_errors=True)
        self.updater = self.record = None

    @staticmethod
    def _release_bytes(updater: Updater, work: Path) -> bytes:
        """The record's bytes."""
        info = updater.get_targetinfo(records.NAME)
        if info is None:
            raise Refused(MALFORMED, f"the signed targets name no {records.NAME}: not a fleet release repository")
        target = work / ".release.json"
        updater.download_target(info, str(target))
        data = target.read_bytes()
        target.unlink()
        return data

    def download(self, paths, directory) -> dict[str, Path]:
        """Each TUF target in ``paths`` (e.g. the record's code archive and
        wheels) into ``directory``/<path>, verified (length and sha256 the
        signed targets give), kept if already there and verified; written as
        a temp file, then renamed.  Refused (TAMPERED, UNAVAILABLE, ...) if one
        cannot be had.  Call after refresh()."""
        if self.updater is None:
            raise RuntimeError("download() before a successful refresh()")
        directory = Path(directory)
        found: dict[str, Path] = {}
        for path in paths:
            if path.startswith("/") or ".." in path.split("/") or not path:
                raise Refused(MALFORMED, f"{path!r}: not a target path")
            try:
                info = self.updater.get_targetinfo(path)
                if info is None:
                    raise Refused(MALFORMED, f"{path}: not in the signed targets")
                destination = directory / path
                destination.parent.mkdir(parents=True, exist_ok=True)
                if not self.updater.find_cached_target(info, str(destination)):
                    partial = destination.with_name(f".{destination.name}.{secrets.token_hex(4)}.part")
                    try:
                        self.updater.download_target(info, str(partial))
                        os.replace(partial, destination)
                    finally:
                        partial.unlink(missing_ok=True)
            except Refused:
                raise
            except Exception as error:  # classified, never let through
                refused = classified(error)
                raise Refused(refused.reason, f"{path}: {refused.line}") from None
            found[path] = destination
        return found


def newest(state_dir, sources: list[str], applied: int = 0, clock=_now) -> Client:
    """Each of ``sources`` (a mounted medium, the fetched releases branch)
    verified from the same trusted state; the client of the newest record
    is kept (on equal versions a halt, else the first source); the others'
    trial is dropped.  Refused: none verified (the first source's refusal,
    the others' lines after it)."""
    Client(state_dir, "")._check_root()
    _sweep(Path(state_dir))
    tried, refused = [], []
    for source in sources:
        client = Client(state_dir, source, clock)
        try:
            client.trial(applied)
            tried.append(client)
        except Refused as error:
            refused.append(error)
    if not tried:
        raise Refused(refused[0].reason, "; ".join(error.line for error in refused))
    chosen = max(tried, key=lambda client: (client.record.version, client.record.halt))
    for client in tried:
        if client is not chosen:
            client.discard()
    chosen.keep()
    return chosen


def _https_fetcher() -> FetcherInterface:
    from tuf.ngclient import Urllib3Fetcher

    return Urllib3Fetcher(app_user_agent="robotfleet")
