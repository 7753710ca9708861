"""The operator's signing keys: ed25519, in a directory outside the
repository, one PEM file (PKCS#8, mode 0600) and one public file per key.

    <keys>/root.key     root.pub       the root key: signs only a new root (keep it offline)
    <keys>/online.key   online.pub     signs targets, snapshot and timestamp (each publish)
    <keys>/online.next.key ...         a replacement online key waiting for its root change

The directory: ``--keys DIR``, else $ROBOTFLEET_KEYS, else
~/.config/robotfleet/keys (made 0700).  Private keys are never printed; a
key file readable by others is refused.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

from securesystemslib.signer import CryptoSigner, SSlibKey

ROOT, ONLINE = "root", "online"
ENV = "ROBOTFLEET_KEYS"


class KeyProblem(Exception):
    """A key that cannot be used; the message is one line."""


def default_dir() -> Path:
    if os.environ.get(ENV):
        return Path(os.environ[ENV])
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return Path(base, "robotfleet", "keys")


def _write_private(path: Path, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "wb") as handle:
        handle.write(data)


def public_of(path) -> SSlibKey:
    """The public key in a ``.pub`` file written by generate()."""
    try:
        raw = json.loads(Path(path).read_text())
        return SSlibKey.from_dict(raw["keyid"], dict(raw["key"]))
    except FileNotFoundError:
        raise KeyProblem(
            f"{path}: no such public key file; give the .pub file robotfleet keys generate wrote beside its key"
        ) from None
    except (ValueError, KeyError, TypeError) as error:
        raise KeyProblem(f"{path}: not a robotfleet public key file ({error})") from None


def signer_of(path) -> CryptoSigner:
    """The signer of a private key file (``X.key``; its ``X.pub`` beside it,
    else the public key is derived).  Refused if others may read it."""
    from cryptography.hazmat.primitives.serialization import load_pem_private_key

    path = Path(path)
    try:
        info = os.stat(path)
        if info.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise KeyProblem(f"{path}: readable by others (mode {stat.S_IMODE(info.st_mode):o}); chmod 600 it")
        private = load_pem_private_key(path.read_bytes(), None)
    except FileNotFoundError:
        raise KeyProblem(
            f"{path}: no such key file; give a .key file robotfleet keys init or keys generate made"
        ) from None
    except (ValueError, TypeError) as error:
        raise KeyProblem(f"{path}: not a PEM private key ({str(error).splitlines()[0]})") from None
    public = path.with_suffix(".pub")
    return CryptoSigner(private, public_of(public) if public.exists() else None)


def generate(path) -> SSlibKey:
    """A new ed25519 key: ``path`` (private, 0600) and ``path`` with .pub;
    refuses to overwrite either.  Its public key."""
    path = Path(path)
    if path.suffix != ".key":
        raise KeyProblem(f"{path}: a private key file's name ends in .key; name it NAME.key")
    public = path.with_suffix(".pub")
    for existing in (path, public):
        if existing.exists() or existing.is_symlink():
            raise KeyProblem(f"{existing}: already exists; a key is never overwritten")
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    signer = CryptoSigner.generate_ed25519()
    _write_private(path, signer.private_bytes)
    public.write_text(
        json.dumps({"keyid": signer.public_key.keyid, "key": signer.public_key.to_dict()}, indent=1, sort_keys=True)
        + "\n"
    )
    return signer.public_key


class KeyDir:
    """The key directory: ``name`` is root, online or online.next."""

    def __init__(self, path=None):
        self.path = Path(path) if path else default_dir()

    def file(self, name: str) -> Path:
        return self.path / f"{name}.key"

    def has(self, name: str) -> bool:
        return self.file(name).exists()

    def generate(self, name: str) -> SSlibKey:
        if self.path.exists() and stat.S_IMODE(self.path.stat().st_mode) & 0o077:
            raise KeyProblem(f"{self.path}: the key directory is open to others; chmod 700 it")
        return generate(self.file(name))

    def public(self, name: str) -> SSlibKey:
        return public_of(self.file(name).with_suffix(".pub"))

    def signer(self, name: str) -> CryptoSigner:
        if not self.has(name):
            raise KeyProblem(f"{self.file(name)}: no {name} key here (robotfleet keys init; --keys DIR or ${ENV})")
        return signer_of(self.file(name))

    def promote(self, name: str, replaced: str) -> None:
        """``name`` (online.next) becomes ``replaced`` (online); the old one is kept as .old."""
        for suffix in (".key", ".pub"):
            old = self.file(replaced).with_suffix(suffix)
            if old.exists():
                os.replace(old, old.with_name(f"{replaced}.old{suffix}"))
            os.replace(self.file(name).with_suffix(suffix), old)
