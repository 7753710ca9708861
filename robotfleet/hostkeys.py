"""known_hosts files: fingerprints as OpenSSH shows them, lookups, and
writing a host's key once, atomically.

Lines are written unhashed (``[10.20.0.11]:2222 ssh-ed25519 AAAA...``): the
fleet's known_hosts lives in the deploy repository beside robots.yaml, which
names every address anyway, so hashing would hide nothing and would make the
file impossible to review in a diff or to grep for a robot.  Hashed lines
already in a file are read (paramiko reads both).

A known_hosts file may also hold ``@cert-authority`` lines (host
certificates, robotfleet/hostcerts.py) and ``@revoked`` lines.  Paramiko
cannot read either and gives up on the whole file at the first one, so the
file is read here, line by line: plain lines as paramiko would, marker lines
kept apart, lines nothing can read skipped.
"""

from __future__ import annotations

import base64
import fnmatch
import hashlib
import hmac
import os
from dataclasses import dataclass, field

from paramiko import HostKeys
from paramiko.hostkeys import HostKeyEntry

from robotfleet import atomicfile

CERT_AUTHORITY, REVOKED = "@cert-authority", "@revoked"


def fingerprint(key) -> str:
    """SHA256:... as ``ssh-keygen -lf`` and ssh's prompts show it."""
    digest = hashlib.sha256(key.asbytes()).digest()
    return "SHA256:" + base64.b64encode(digest).decode().rstrip("=")


def entry(address: str, port: int) -> str:
    """How known_hosts names a host: the address, ``[address]:port`` off port 22."""
    return address if int(port) == 22 else f"[{address}]:{port}"


@dataclass
class KnownHosts:
    """A known_hosts file as OpenSSH reads it: the plain keys, the host CAs
    (host patterns, CA key) and the revoked keys."""

    plain: HostKeys = field(default_factory=HostKeys)
    authorities: list[tuple[list[str], object]] = field(default_factory=list)
    revoked: list = field(default_factory=list)

    def revoked_key(self, key) -> bool:
        return any(key == other for other in self.revoked)

    def usable(self) -> HostKeys:
        """A copy of the plain keys without the revoked ones (OpenSSH refuses
        a revoked key whatever else the file says)."""
        keys = HostKeys()
        keys._entries = [e for e in self.plain._entries if not self.revoked_key(e.key)]
        return keys

    def authorities_for(self, name: str) -> list:
        """The CA keys whose host patterns match ``name`` (a known_hosts entry)."""
        return [ca for patterns, ca in self.authorities if matches(patterns, name)]


def _entry(text: str):
    try:
        return HostKeyEntry.from_line(text)
    except Exception:  # a line paramiko cannot read (an unknown key type, bad base64): skipped, as ssh does
        return None


def read(path: str) -> KnownHosts:
    found = KnownHosts()
    if not os.path.exists(path):
        return found
    with open(path, encoding="utf-8", errors="replace") as handle:
        for line in handle:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            marker = None
            if line.startswith("@"):
                marker, _, line = line.partition(" ")
            entry = _entry(line.strip())
            if entry is None or entry.key is None:
                continue
            if marker == CERT_AUTHORITY:
                found.authorities.append((entry.hostnames, entry.key))
            elif marker == REVOKED:
                found.revoked.append(entry.key)
            elif marker is None:
                for name in entry.hostnames:
                    found.plain.add(name, entry.key.get_name(), entry.key)
    return found


def load(path: str) -> HostKeys:
    return read(path).plain


_CACHE: dict[str, tuple[tuple, KnownHosts]] = {}


def cached(path: str) -> KnownHosts:
    """read(path), read again only when the file changed (a run connects to
    every host of a fleet with the same file)."""
    try:
        info = os.stat(path)
        stamp = (info.st_mtime_ns, info.st_size, info.st_ino)
    except OSError:
        stamp = None
    hit = _CACHE.get(path)
    if hit is None or hit[0] != stamp:
        hit = _CACHE[path] = (stamp, read(path))
    return hit[1]


def _hashed(pattern: str, name: str) -> bool:
    salt = pattern.split("|")[2] if pattern.count("|") >= 3 else ""
    try:
        return hmac.compare_digest(HostKeys.hash_host(name, salt), pattern)
    except Exception:  # not a valid hashed name
        return False


def _same(stored: str, name: str) -> bool:
    """A plain line's name is ``name`` (as paramiko looks names up: exact, or hashed)."""
    return _hashed(stored, name) if stored.startswith("|1|") else stored == name


def _one(pattern: str, name: str) -> bool:
    if pattern.startswith("|1|"):
        return _hashed(pattern, name)
    return fnmatch.fnmatchcase(name.lower(), pattern.lower().replace("[", "[[]"))


def matches(patterns: list[str], name: str) -> bool:
    """OpenSSH's host pattern list: a match, and no negated (!) pattern matching."""
    if any(p.startswith("!") and _one(p[1:], name) for p in patterns):
        return False
    return any(not p.startswith("!") and _one(p, name) for p in patterns)


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
    lines = [
        HostKeyEntry([name], key).to_line()
        for name, key in entries
        if (current.lookup(name) or {}).get(key.get_name()) != key
    ]
    lines = list(dict.fromkeys(lines))
    if not lines:
        return 0
    text = _text(path)
    if text and not text.endswith("\n"):
        text += "\n"
    _write(path, text + "".join(lines))
    return len(lines)


def replace(path: str, name: str, key) -> list:
    """Make ``key`` the one key of ``name`` (an entry): every plain line for
    it (hashed ones too) loses that name, then the new line is added; the
    keys removed.  Marker lines and other hosts' lines stay as they are."""
    kept, removed = [], []
    for line in _text(path).splitlines(keepends=True):
        words = line.split()
        entry = None if not words or words[0].startswith(("#", "@")) else _entry(line.strip())
        if entry is None or not any(_same(n, name) for n in entry.hostnames):
            kept.append(line if line.endswith("\n") else line + "\n")
            continue
        removed.append(entry.key)
        others = [n for n in entry.hostnames if not _same(n, name)]
        if others:
            kept.append(" ".join([",".join(others), *words[1:]]) + "\n")
    _write(path, "".join(kept) + HostKeyEntry([name], key).to_line())
    return removed


def _text(path: str) -> str:
    try:
        with open(path, encoding="utf-8") as handle:
            return handle.read()
    except FileNotFoundError:
        return ""


def _write(path: str, text: str) -> None:
    """Replace the file whole (robotfleet/atomicfile.py), keeping its mode; a new one is 0644."""
    atomicfile.write(path, text, mode=0o644, make_parents=True, keep_mode=True)
