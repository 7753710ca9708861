"""What counts as a secret in a host's data, and text with them masked.

One rule decides both what output masks (inventory, --diff, the deploy's
log, the fleet file's problem lines) and what a release refuses to carry
(robotfleet/pull/operator/publishing.py):

- the password of every URL anywhere in the data (a proxy's, a mirror's,
  one in a payload environment value);
- the value of a key whose last word names a secret (``named_secret``):
  token, secret, pass, passwd, password, passphrase, key, credential, their
  plurals, or a word ending in one (dbpassword, authToken, APIKey),
  case-insensitive: API_TOKEN, AWS_SECRET_ACCESS_KEY, ssh_key_password,
  clientSecret; a number there too (an unquoted PIN).  The last word,
  because that is what the key names: KEY_FINGERPRINT, AWS_ACCESS_KEY_ID,
  token_realms, *_password_env and *_key_file name something about a
  secret, not the secret, and a public or host key (JWT_PUBLIC_KEY) is none.  A path (``/dir/...``, ``~/...``; and
  the settings that name a file, pyinfra's ``ssh_key`` and
  ``ssh_revoked_host_keys``, whatever their form) says where a secret is
  kept, not what it is: a key file's path is shown and may travel, the key
  in it does neither;
- what the roles say they hold (``Role.secrets``: the registry passwords,
  the payload's secret files).

Masked by value, whatever characters they contain, in the forms they take
in a file (as written, percent-decoded, JSON-escaped).  Text the fleet did
not write (the file on the host, with an older password) is masked by
shape too: the password of every URL in it.
"""

from __future__ import annotations

import json
import re
import urllib.parse
from collections.abc import Iterable

MASK = "****"
# scheme://user:password@ — the password up to the last @ of the authority
# (as URL parsers read it), JSON escapes (\") included.
_URL_PASSWORD = re.compile(r"([A-Za-z][A-Za-z0-9+.-]*://[^\s/?#\"'\\:@]*):((?:\\.|[^\s/?#\"\\])*)@")
_SCHEME = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*://")

_held: dict[str, frozenset[str]] = {}


def url_passwords(text: str) -> set[str]:
    """The passwords of the URLs in ``text``, as URL parsers read them and as
    a looser reading would (up to the last @ of the URL): both are masked."""
    found = set()
    for start in (m.end() for m in _SCHEME.finditer(text)):
        rest = text[start:]
        for candidate in {rest, rest.split()[0] if rest.split() else ""}:
            userinfo, at, _ = candidate.rpartition("@")
            if at and ":" in userinfo:
                found.add(userinfo.split(":", 1)[1])
            try:
                password = urllib.parse.urlsplit("//" + candidate).password
            except ValueError:
                password = None
            if password:
                found.add(password)
    return {p for p in found if p}


# The last word of a key that names a secret, and the ends of a word that do.
_SECRET_WORDS = frozenset(
    "token tokens secret secrets pass passwd password passwords passphrase key keys credential credentials".split()
)
_SECRET_ENDS = ("password", "passwd", "passphrase", "token", "secret", "credentials", "apikey", "privatekey")
# A key of these is public (JWT_PUBLIC_KEY, pull_remote_host_keys).
_PUBLIC = frozenset({"public", "pub", "host"})
# Settings whose value is a file name by definition (pyinfra's ssh_key: the key is in the file).
_FILE_NAMES = frozenset({"ssh_key", "ssh_revoked_host_keys"})
# /dir/... or ~/...: where a secret is kept.  The first directory is a plain
# name (a random token that starts with "/" is very unlikely to read so).
_PATH = re.compile(r"(?:~|/[a-z0-9_.-]*[a-z][a-z0-9_.-]*)(?:/[A-Za-z0-9_.@-]+)+/?")
_WORDS = re.compile(r"[^A-Za-z0-9]+|(?<=[a-z0-9])(?=[A-Z])")


def named_secret(key: str) -> bool:
    """Whether a value under ``key`` is a secret, by the key's last word."""
    words = [w for w in _WORDS.split(str(key)) if w]
    if not words or key in _FILE_NAMES:
        return False
    last = words[-1].lower()
    if last in ("key", "keys") and len(words) > 1 and words[-2].lower() in _PUBLIC:
        return False
    return last in _SECRET_WORDS or last.endswith(_SECRET_ENDS)


def is_path(value: str) -> bool:
    """A path to a file (``/run/secrets/db``, ``~/.ssh/id_ed25519``): where a secret is, not the secret."""
    return _PATH.fullmatch(value) is not None


def found_in(data) -> list[tuple[str, str]]:
    """Every secret in a host's data (any nesting), each with the field that
    holds it (``payload_environment.API_TOKEN``, ``docker_daemon_options.proxies.http-proxy``),
    in the data's order: the URL passwords, and the values of keys that name a secret."""
    found: list[tuple[str, str]] = []
    # A container met again (a YAML alias) holds nothing new: walked once, however often it is
    # referred to, so an alias bomb costs its size, not its expansion.
    walked: set[int] = set()

    def walk(value, field: str, key: str = ""):
        if isinstance(value, (dict, list, tuple, set, frozenset)):
            if id(value) in walked:
                return
            walked.add(id(value))
        if isinstance(value, str):
            found.extend((field, password) for password in sorted(url_passwords(value)))
            if value and named_secret(key) and not is_path(value):
                found.append((field, value))
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and named_secret(key):
            found.append((field, str(value)))  # a PIN or a numeric token, unquoted in YAML
        elif isinstance(value, dict):
            for k, item in value.items():
                walk(item, f"{field}.{k}" if field else str(k), str(k))
        elif isinstance(value, (list, tuple, set, frozenset)):
            # A list's items are not its key's values one by one (compose's secrets: [name] lists names).
            for index, item in enumerate(value):
                walk(item, f"{field}[{index}]")

    walk(data, "")
    return found


def held_in(data) -> set[str]:
    """Every secret in a host's data (found_in's values)."""
    return {secret for _, secret in found_in(data)}


def forms(secret: str) -> set[str]:
    """How ``secret`` may appear in a file: as it is, percent-decoded, and JSON-escaped."""
    out = {secret, urllib.parse.unquote(secret)}
    for value in list(out):
        out.add(json.dumps(value)[1:-1])
        out.add(json.dumps(value, ensure_ascii=False)[1:-1])
    return {f for f in out if f}


def mask(text: str, secrets: Iterable[str] = ()) -> str:
    """``text`` with each of ``secrets`` (in every form) and every URL password masked."""
    for form in sorted({f for s in secrets for f in forms(s)}, key=len, reverse=True):
        text = text.replace(form, MASK)
    return _URL_PASSWORD.sub(lambda m: f"{m.group(1)}:{MASK}@", text)


def hold(host_name: str, secrets: Iterable[str]) -> None:
    """Remember ``host_name``'s secrets for the masking of its output."""
    _held[host_name] = frozenset(s for s in secrets if s)


def of(host_name: str) -> frozenset[str]:
    return _held.get(host_name, frozenset())
