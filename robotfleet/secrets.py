"""The secrets a host's data holds, and text with them masked (--diff).

Masked by value: every password of a URL anywhere in the host's data (a
proxy's, a mirror's, one in a payload environment value), every ``*_password``
value (pyinfra's ssh_password, ssh_key_password) and what the roles say they
hold (``Role.secrets``: the registry passwords), whatever characters they
contain; in the forms they take in a file (as written, percent-decoded,
JSON-escaped).  Text the fleet did not write (the file on the host, with an
older password) is masked by shape too: the password of every URL in it.
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


def held_in(data) -> set[str]:
    """Every secret in a host's data (any nesting): URL passwords and the
    values of keys ending in ``password``."""
    found: set[str] = set()

    def walk(value, key=""):
        if isinstance(value, str):
            found.update(url_passwords(value))
            if key.lower().endswith("password") and value:
                found.add(value)
        elif isinstance(value, dict):
            for k, item in value.items():
                walk(item, str(k))
        elif isinstance(value, (list, tuple, set, frozenset)):
            for item in value:
                walk(item)

    walk(data)
    return found


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
