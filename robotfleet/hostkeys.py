"""known_hosts files: fingerprints as OpenSSH shows them, lookups, and
writing a host's key once, atomically.

Lines are written unhashed (``[10.20.0.11]:2222 ssh-ed25519 AAAA...``): the
fleet's known_hosts lives in the deploy repository beside robots.yaml, which
names every address anyway, so hashing would hide nothing and would make the
file impossible to review in a diff or to grep for a robot.  Hashed lines
already in a file are read (paramiko reads both).
"""

from __future__ import annotations

import base64
import hashlib
import os
import tempfile

from paramiko import HostKeys
from paramiko.hostkeys import HostKeyEntry


def fingerprint(key) -> str:
    """SHA256:... as ``ssh-keygen -lf`` and ssh's prompts show it."""
    digest = hashlib.sha256(key.asbytes()).digest()
    return "SHA256:" + base64.b64encode(digest).decode().rstrip("=")


def entry(address: str, port: int) -> str:
    """How known_hosts names a host: the address, ``[address]:port`` off port 22."""
    return address if int(port) == 22 else f"[{address}]:{port}"


def load(path: str) -> HostKeys:
    keys = HostKeys()
    if os.path.exists(path):
        keys.load(path)
    return keys


def known(path: str, name: str) -> dict:
    """key type -> key for ``name`` (an entry) in the file at ``path``."""
    found = load(path).lookup(name)
    return dict(found) if found is not None else {}


def append(path: str, name: str, key) -> bool:
    """Add ``name``'s ``key`` unless the file has it; False if it had.
    The file is replaced whole (temp file, fsync, rename): a power cut
    leaves the old file or the new one, never half a line."""
    return add_all(path, [(name, key)]) > 0


def add_all(path: str, entries: list[tuple[str, object]]) -> int:
    """Append each (name, key) not already in the file; the number added."""
    current = load(path)
    lines = [HostKeyEntry([name], key).to_line() for name, key in entries
             if (current.lookup(name) or {}).get(key.get_name()) != key]
    lines = list(dict.fromkeys(lines))
    if not lines:
        return 0
    try:
        with open(path, encoding="utf-8") as handle:
            text = handle.read()
    except FileNotFoundError:
        text = ""
    if text and not text.endswith("\n"):
        text += "\n"
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".known_hosts.", dir=directory)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text + "".join(lines))
            handle.flush()
            os.fsync(handle.fileno())
        if os.path.exists(path):
            os.chmod(tmp, os.stat(path).st_mode & 0o7777)
        else:
            os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise
    return len(lines)
