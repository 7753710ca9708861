"""Blobs of a local git repository read by name, bounded, when what is in
the repository came from others (the robots' reports): one ``git cat-file
--batch`` process for them all, its output streamed.

Each request carries its index (``%(rest)``), so each record is known by
what it answers, not by where it falls; every record is consumed by the
size its header gives, whatever the object's type, so no object's bytes are
ever read as another record.  Only blobs up to ``limit`` bytes are kept in
memory (a larger object is read through and dropped); anything else comes
back as a line saying what it was.
"""

from __future__ import annotations

import os
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path

FORMAT = "%(objectname) %(objecttype) %(objectsize) %(rest)"
CHUNK = 64 * 1024


class CatFileError(Exception):
    """The repository cannot be read (one line)."""


def blobs(repo: Path | str, names: list[str], limit: int, timeout: float = 300) -> list[bytes | str]:
    """For each of ``names`` (``<commit>:<path>``, an object id ...), in
    order: its content if it is a blob of at most ``limit`` bytes, else one
    line saying why not (``missing``, ``a tree, not a blob``, ...)."""
    for name in names:
        if not name or any(c.isspace() for c in name):
            raise ValueError(f"an object name without blanks, not {name!r}")
    if not names:
        return []
    deadline = time.monotonic() + timeout
    request = "".join(f"{name} {index}\n" for index, name in enumerate(names)).encode()
    found: list[bytes | str] = []
    with tempfile.TemporaryFile() as errors:
        try:
            process = subprocess.Popen(
                ["git", "-C", str(repo), "cat-file", f"--batch={FORMAT}"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=errors,
                env=dict(os.environ, LC_ALL="C", GIT_TERMINAL_PROMPT="0"),
                start_new_session=True,
            )
        except OSError as error:
            raise CatFileError(f"cannot run git ({error})") from None
        timer = threading.Timer(timeout, _kill, (process.pid,))
        writer = threading.Thread(target=_write, args=(process.stdin, request), daemon=True)
        timer.start()
        writer.start()
        try:
            for index, name in enumerate(names):
                answer = _record(process.stdout, name, str(index).encode(), limit)
                if answer is None:
                    break
                found.append(answer)
        finally:
            process.stdout.close()
            process.wait()
            timer.cancel()
            writer.join()
        if len(found) == len(names):
            return found
        if time.monotonic() >= deadline:
            raise CatFileError(f"git cat-file: no answer within {timeout:g} s")
        errors.seek(0)
        said = [line.strip() for line in errors.read(4096).decode(errors="replace").splitlines() if line.strip()]
        raise CatFileError(f"git cat-file: {(said[-1] if said else f'exit {process.returncode}')[:200]}")


def _kill(pid: int) -> None:
    try:
        os.killpg(pid, signal.SIGKILL)
    except ProcessLookupError:  # it ended as the time ran out
        pass


def _write(stream, data: bytes) -> None:
    try:
        stream.write(data)
        stream.close()
    except OSError:  # cat-file died: its reader says so
        pass


def _record(out, name: str, tag: bytes, limit: int) -> bytes | str | None:
    """The answer to ``name`` (sent with ``tag``); None if cat-file stopped before giving it whole."""
    header = out.readline(512)
    if not header.endswith(b"\n"):
        return None
    fields = header.split()
    if len(fields) == 2 and fields[0] == name.encode() and fields[1] in (b"missing", b"ambiguous"):
        return fields[1].decode()
    if len(fields) != 4 or fields[3] != tag or not fields[2].isdigit():
        raise CatFileError(f"git cat-file: an answer that is not for {name}: {header[:120]!r}")
    kind, size = fields[1].decode(errors="replace"), int(fields[2])
    if kind == "blob" and size <= limit:
        answer: bytes | str = out.read(size)
        whole = len(answer) == size
    else:
        whole = _skip(out, size)
        answer = f"a {kind}, not a blob" if kind != "blob" else f"larger than {limit} bytes ({size})"
    return answer if whole and out.read(1) == b"\n" else None


def _skip(out, size: int) -> bool:
    """Read ``size`` bytes and keep none; False if the stream ended first."""
    while size:
        chunk = out.read(min(size, CHUNK))
        if not chunk:
            return False
        size -= len(chunk)
    return True
