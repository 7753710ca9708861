"""The directory ``robotfleet export DIR`` writes: a USB stick, an NFS share,
a stick that came back from the field.  None of it is trusted, so nothing
under DIR is ever followed as a link: DIR is opened once, every directory
and file under it through the one above (``dir_fd``, ``O_NOFOLLOW``), and a
link anywhere under it (or a FIFO, a device) refuses the export in one line
naming it, before anything is written.  DIR must be empty (an ext4 stick's
``lost+found`` aside) or hold an earlier export (``metadata/root.json``).

Only the names an export writes are ever replaced or deleted: the TUF
metadata in ``metadata/`` (``root.json``, ``timestamp.json``,
``N.root.json``, ``N.snapshot.json``, ``N.targets.json``) and the target
blobs in ``targets/`` (``<sha256>.<name>``), each written as a temp file
and renamed; a blob already there is kept only when its bytes are the
signed ones, and rewritten otherwise.  Anything else (the robots'
``reports/``, a file the operator keeps there) stays as it was.
"""

from __future__ import annotations

import hashlib
import os
import re
import stat

# Where DIR may be reached through a link the operator chose (a mount
# point's symlink): only what is under it is never followed.
_DIR = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
_NEW = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
METADATA_NAME = re.compile(r"(root|timestamp|[1-9][0-9]{0,9}\.(root|snapshot|targets))\.json\Z")
BLOB_NAME = re.compile(r"[0-9a-f]{64}\.[^/]+\Z")
TEMP_NAME = re.compile(r"\..+\.[0-9a-f]{12}\.tmp\Z")  # what an interrupted write of ours left
EMPTY_ENOUGH = {"lost+found"}  # what mkfs.ext4 leaves on a new stick
CHUNK = 1 << 20


class MediumError(Exception):
    """Nothing was written to the medium; the message is one line."""


class Medium:
    """``path``, opened once (``open()``) and walked without following a link."""

    def __init__(self, path):
        self.path = os.fspath(path)
        self.fd = -1

    def __enter__(self) -> Medium:
        try:
            os.makedirs(self.path, exist_ok=True)
            self.fd = os.open(self.path, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        except OSError as error:
            raise MediumError(f"{self.path}: cannot be opened as a directory ({error.strerror or error})") from None
        self._check()
        return self

    def __exit__(self, *exc) -> None:
        os.close(self.fd)

    # -- what is there --------------------------------------------------------

    def _check(self) -> None:
        """Refuse a link or a special file anywhere under DIR, and a DIR that
        is neither (nearly) empty nor an earlier export."""
        top = self._walk(self.fd, "")
        if not set(top) - EMPTY_ENOUGH:
            return
        if top.get("metadata") == "dir" and self._kind("metadata/root.json") == "file":
            return
        shown = ", ".join(sorted(set(top) - EMPTY_ENOUGH)[:3])
        raise MediumError(
            f"{self.path}: neither empty nor an earlier export (it holds {shown}): "
            "give an empty directory, or the medium of an earlier export"
        )

    def _walk(self, fd: int, where: str) -> dict[str, str]:
        """{name: 'dir' | 'file'} of the directory ``fd``; its subdirectories walked too."""
        found = {}
        with os.scandir(fd) as entries:
            for entry in entries:
                shown = f"{self.path}/{where}{entry.name}"
                if entry.is_symlink():
                    raise MediumError(f"{shown}: a symbolic link on the medium; nothing was exported (remove it)")
                if entry.is_dir(follow_symlinks=False):
                    found[entry.name] = "dir"
                    sub = self._open_dir(fd, entry.name, shown)
                    try:
                        self._walk(sub, f"{where}{entry.name}/")
                    finally:
                        os.close(sub)
                elif entry.is_file(follow_symlinks=False):
                    found[entry.name] = "file"
                else:
                    raise MediumError(f"{shown}: neither a file nor a directory; nothing was exported (remove it)")
        return found

    def _open_dir(self, fd: int, name: str, shown: str) -> int:
        try:
            return os.open(name, _DIR, dir_fd=fd)
        except OSError as error:
            if _is_link(fd, name):
                raise MediumError(f"{shown}: a symbolic link on the medium; nothing was exported (remove it)") from None
            raise MediumError(f"{shown}: cannot be opened ({error.strerror})") from None

    def _kind(self, path: str) -> str | None:
        directory, _, name = path.rpartition("/")
        fd = self._directory(directory, create=False)
        if fd is None:
            return None
        try:
            mode = os.lstat(name, dir_fd=fd).st_mode
        except FileNotFoundError:
            return None
        finally:
            os.close(fd)
        return "file" if stat.S_ISREG(mode) else "dir" if stat.S_ISDIR(mode) else "other"

    def _directory(self, path: str, create: bool) -> int | None:
        """An fd of the directory ``path`` (relative, '' for DIR), each part
        opened without following a link (and made when ``create``)."""
        fd = os.dup(self.fd)
        for part in [p for p in path.split("/") if p]:
            shown = f"{self.path}/{path}"
            if create:
                try:
                    os.mkdir(part, 0o755, dir_fd=fd)
                except FileExistsError:
                    pass
            try:
                sub = os.open(part, _DIR, dir_fd=fd)
            except FileNotFoundError:
                os.close(fd)
                return None
            except OSError as error:
                linked = _is_link(fd, part)
                os.close(fd)
                what = "a symbolic link on the medium" if linked else f"cannot be opened ({error.strerror})"
                raise MediumError(f"{shown}: {what}") from None
            os.close(fd)
            fd = sub
        return fd

    # -- writing ----------------------------------------------------------------

    def has(self, path: str, length: int, sha256: str) -> bool:
        """Whether the regular file ``path`` holds exactly ``length`` bytes of that hash."""
        directory, _, name = path.rpartition("/")
        fd = self._directory(directory, create=False)
        if fd is None:
            return False
        try:
            file = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, dir_fd=fd)
        except OSError:
            return False
        finally:
            os.close(fd)
        with os.fdopen(file, "rb") as handle:
            if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
                return False
            digest, size = hashlib.sha256(), 0
            while chunk := handle.read(CHUNK):
                digest.update(chunk)
                size += len(chunk)
        return size == length and digest.hexdigest() == sha256

    def write(self, path: str, source, length: int | None = None, sha256: str | None = None) -> None:
        """``path`` replaced by the bytes of ``source`` (bytes, or a file
        opened for reading), through a temp file renamed over it; with
        ``length`` and ``sha256``, MediumError when what was copied is not that."""
        directory, _, name = path.rpartition("/")
        self._ours(directory, name)
        fd = self._directory(directory, create=True)
        temp = f".{name}.{os.urandom(6).hex()}.tmp"
        try:
            out = os.open(temp, _NEW, 0o600, dir_fd=fd)
            digest, size = hashlib.sha256(), 0
            with os.fdopen(out, "wb") as handle:
                for chunk in [source] if isinstance(source, bytes) else iter(lambda: source.read(CHUNK), b""):
                    handle.write(chunk)
                    digest.update(chunk)
                    size += len(chunk)
                handle.flush()
                os.fsync(handle.fileno())
                os.fchmod(handle.fileno(), 0o644)
            if sha256 is not None and (size, digest.hexdigest()) != (length, sha256):
                raise MediumError(f"{path}: the copy differs from what was signed; nothing more was exported")
            os.replace(temp, name, src_dir_fd=fd, dst_dir_fd=fd)
            temp = None
        finally:
            if temp is not None:
                _unlink(fd, temp)
            os.close(fd)

    def prune(self, directory: str, keep: set[str]) -> None:
        """Delete under ``directory`` ('metadata' or 'targets', walked down)
        what an export writes that is not in ``keep`` (paths relative to DIR)."""
        fd = self._directory(directory, create=False)
        if fd is None:
            return
        try:
            self._prune(fd, directory, keep)
        finally:
            os.close(fd)

    def _prune(self, fd: int, where: str, keep: set[str]) -> None:
        pattern = METADATA_NAME if where == "metadata" else BLOB_NAME
        with os.scandir(fd) as entries:
            for entry in list(entries):
                path = f"{where}/{entry.name}"
                if entry.is_dir(follow_symlinks=False) and where != "metadata":
                    sub = self._open_dir(fd, entry.name, f"{self.path}/{path}")
                    try:
                        self._prune(sub, path, keep)
                    finally:
                        os.close(sub)
                elif entry.is_file(follow_symlinks=False) and path not in keep:
                    if pattern.match(entry.name) or TEMP_NAME.match(entry.name):
                        _unlink(fd, entry.name)

    def _ours(self, directory: str, name: str) -> None:
        top = directory.split("/", 1)[0]
        pattern = METADATA_NAME if directory == "metadata" else BLOB_NAME if top == "targets" else None
        if pattern is None or not pattern.match(name):
            raise MediumError(f"{directory}/{name}: not a name an export writes")


def _is_link(fd: int, name: str) -> bool:
    try:
        return stat.S_ISLNK(os.lstat(name, dir_fd=fd).st_mode)
    except OSError:
        return False


def _unlink(fd: int, name: str) -> None:
    try:
        os.unlink(name, dir_fd=fd)
    except FileNotFoundError:
        pass
