"""Kinds of values several roles' settings share: addresses, URLs, paths on
a host, paths on this machine, OpenPGP fingerprints.  Each is a checker
(robotfleet/checkers.py) carrying its JSON Schema."""

from __future__ import annotations

import posixpath
import re

from robotfleet import checkers as c

# URLs reach root shells and apt sources on every robot: http(s) only, and no
# character a shell or an apt line gives a meaning to (no $ ` ; | & quotes,
# spaces, backslashes, parentheses, < >).
URL = r"https?://(?:[A-Za-z0-9._~-]+|\[[0-9A-Fa-f:.]+\])(?::[0-9]{1,5})?(?:/[A-Za-z0-9._~%/+,=@:-]*)?(?:\?[A-Za-z0-9._~%/+,=@:-]*)?"
URL_WHAT = "an http(s) URL without spaces or shell characters ($ ` ; | & quotes)"
# Directories anyone may write to (or, /run/user, a user owns): a path at or
# below one can be planted or swapped by a local user before root creates,
# chmods or reads it.
WORLD_WRITABLE = ("/tmp", "/var/tmp", "/dev/shm", "/run/lock", "/dev/mqueue", "/run/user")
# Other names of those directories on Debian and Ubuntu (symlinks there):
# /var/run -> /run, /var/lock -> /run/lock, /run/shm -> /dev/shm.
ALIASES = (("/var/run", "/run"), ("/var/lock", "/run/lock"), ("/run/shm", "/dev/shm"))
# Where a path root creates, chmods, writes or trusts may be: places only root
# writes on stock Debian and Ubuntu.  An allowlist, because the places others
# may write keep turning up (/var/crash is world-writable on Ubuntu, /var/mail
# is group mail's, /var/local group staff's, /var/spool holds both kinds,
# /home and /media belong to users): anything not listed is refused.
# /proc/driver holds kernel drivers' files (gpu_driver_version_file).
ROOT_ONLY = (
    "/etc",
    "/opt",
    "/srv",
    "/mnt",
    "/root",
    "/usr",
    "/var/lib",
    "/var/opt",
    "/var/cache",
    "/var/log",
    "/run",
    "/proc/driver",
)
# Inside those, directories others may write: /usr/local is 2775 root:staff on
# older Debian; PHP's session directory is 1733.
SHARED_INSIDE = ("/usr/local", "/var/lib/php/sessions")
# Why a few places outside ROOT_ONLY are refused, said in the refusal.
NOT_ROOT_ONLY = {
    "/var/crash": "world-writable on Ubuntu (crash reports)",
    "/var/spool": "holds directories others write (mail, cron, print queues)",
    "/var/mail": "writable by group mail",
    "/var/local": "writable by group staff",
    "/var/metrics": "world-writable on Ubuntu",
    "/home": "users own their home directories",
    "/media": "users' removable media (mounted for them)",
    "/usr/local": "writable by group staff on older Debian",
    "/var/lib/php/sessions": "world-writable (1733)",
}


def canonical(path: str) -> str:
    """``path`` normalized, with the known aliases of system directories
    resolved (as the host would resolve them)."""
    normal = "/" + posixpath.normpath(path).lstrip("/")
    changed = True
    while changed:
        changed = False
        for alias, target in ALIASES:
            if normal == alias or normal.startswith(alias + "/"):
                normal = target + normal[len(alias) :]
                changed = True
    return normal


_DOTTED_NUMBERS = re.compile(r"[0-9.]+")
_HOST_PORT = re.compile(r"([^:\s\[\]]+|\[[^\]]*\]):([0-9]+)")
_LABEL = r"[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?"
# A DNS name whose last label is not all digits (1.2.3.300 is a bad IPv4 address, not a name).
DNS_NAME = rf"(?=.{{1,253}}$|.{{1,253}}\.$)(?:{_LABEL}\.)*(?![0-9]+\.?$){_LABEL}\.?"
_OCTET = r"(?:25[0-5]|2[0-4][0-9]|1[0-9]{2}|[1-9]?[0-9])"
IPV4 = rf"(?:{_OCTET}\.){{3}}{_OCTET}"
_H = r"[0-9A-Fa-f]{1,4}"
# RFC 4291 text forms: eight groups, one :: standing for one or more zero
# groups, an IPv4 address as the last 32 bits; a zone (%eth0) may follow.
_V6_LAST = rf"(?:{_H}:{_H}|{IPV4})"  # the last 32 bits: two groups or an IPv4 address


def _after_gap(groups: int) -> str:
    """At most ``groups`` groups after '::' (an IPv4 address counts two)."""
    options = [rf"(?:{_H}:){{0,{groups - 1}}}{_H}"] + (
        [rf"(?:{_H}:){{0,{groups - 2}}}{_V6_LAST}"] if groups >= 2 else []
    )
    return "(?:" + "|".join(options) + ")?"


IPV6_NO_ZONE = (
    rf"(?:(?:{_H}:){{6}}{_V6_LAST}"
    rf"|::{_after_gap(7)}"
    + "".join(rf"|(?:{_H}:){{{before}}}{_H}::{_after_gap(6 - before)}" for before in range(6))
    + rf"|(?:{_H}:){{6}}{_H}::)"
)
IPV6 = IPV6_NO_ZONE + r"(?:%[0-9A-Za-z._~-]+)?"
ADDRESS = rf"{IPV4}|{IPV6}|{DNS_NAME}"
_ADDRESS = re.compile(ADDRESS, re.ASCII)

url = c.string(URL, URL_WHAT)
user_name = c.string(c.USER_NAME, "a user name")
package_name = c.string(r"[a-z0-9][a-z0-9.+-]+", "a package name")
apt_version = c.string(r"[0-9][0-9A-Za-z.+~:-]*", "an apt version string")
file_name = c.string(r"[A-Za-z0-9][A-Za-z0-9_.-]*", "a file name")


def address(value):
    """A host name, an IPv4 or an IPv6 address (what SSH connects to): the
    verdict is ADDRESS, the schema's pattern; the rest says why not."""
    if not isinstance(value, str):
        return [("", c.expected_string(value, "a host name or an IP address"))]
    if _ADDRESS.fullmatch(value):
        return []
    if value.startswith("[") and value.endswith("]"):
        return [("", f"expected an IPv6 address without brackets, got {c.shown(value)}")]
    host_port = _HOST_PORT.fullmatch(value)
    if host_port:
        return [
            (
                "",
                f"expected a host name or an IP address, got {c.shown(value)}; put the port in ssh_port: "
                f"{host_port.group(2)}",
            )
        ]
    if _DOTTED_NUMBERS.fullmatch(value):
        return [("", f"{c.shown(value)} is not a valid IPv4 address")]
    return [("", f"expected a host name or an IP address, got {c.shown(value)}")]


# Characters that do not print as themselves: C0 and C1 controls, spaces
# other than the space, zero-width and direction-changing marks, line and
# paragraph separators, the byte-order mark.
_UNPRINTED = "\\x00-\\x1f\\x7f-\\xa0\\u1680\\u180e\\u2000-\\u200f\\u2028-\\u202f\\u205f-\\u206f\\u3000\\ufeff"
LOCAL_PATH = f"[^{_UNPRINTED}]+"
_LOCAL_PATH = re.compile(LOCAL_PATH)


def local_path(value):
    """A file on the operator's machine (never sent to a host): any path
    that prints as itself (no control, invisible or direction-changing characters)."""
    if not isinstance(value, str):
        return [("", c.expected_string(value, "a path on this machine"))]
    if not _LOCAL_PATH.fullmatch(value):
        return [("", f"expected a path on this machine of printable characters, got {c.shown(value)}")]
    return []


def abs_path(value):
    problems = c.string(c.ABS_PATH, "an absolute path")(value)
    if not problems and ".." in value.split("/"):
        return [("", f"paths must not contain '..', got {c.shown(value)}")]
    return problems


def _under(path: str, places) -> str | None:
    return next((place for place in places if path == place or path.startswith(place + "/")), None)


def private_path(value):
    """A path root creates, chmods, writes or trusts: in a place only root
    writes (ROOT_ONLY), not in a directory others may write."""
    problems = abs_path(value)
    if problems:
        return problems
    normal = canonical(value)
    shared = _under(normal, WORLD_WRITABLE)
    if shared:
        return [
            (
                "",
                f"{c.shown(value)} is in the world-writable {shared}; "
                "use a directory only root can write (e.g. under /var/lib)",
            )
        ]
    shared = _under(normal, SHARED_INSIDE) or (None if _under(normal, ROOT_ONLY) else _under(normal, NOT_ROOT_ONLY))
    if shared:
        return [
            (
                "",
                f"{c.shown(value)} is in {shared}, {NOT_ROOT_ONLY[shared]}; use a directory only root can write "
                "(e.g. under /var/lib)",
            )
        ]
    if not _under(normal, ROOT_ONLY):
        return [
            (
                "",
                f"{c.shown(value)} is not in a place only root writes on Debian and Ubuntu "
                f"({', '.join(ROOT_ONLY)}); use a directory there (e.g. under /var/lib)",
            )
        ]
    return []


_FINGERPRINT = c.string(r"[0-9A-Fa-f]{40}", "a 40-digit hex OpenPGP fingerprint")


def fingerprint(value):
    return _FINGERPRINT(value.replace(" ", "") if isinstance(value, str) else value)


def normal_fingerprint(value: str | None) -> str | None:
    """A fingerprint as gpg prints it: no spaces, upper case."""
    return value.replace(" ", "").upper() if value else None


def _spellings(places) -> list[str]:
    """Every way to write ``places``, aliases included (for the editors'
    schema, which cannot resolve them)."""
    found = set(places)
    while True:
        more = {
            alias + path[len(target) :]
            for path in found
            for alias, target in ALIASES
            if path == target or path.startswith(target + "/")
        }
        if more <= found:
            return sorted(found)
        found |= more


_SEP = r"/(?:\.?/)*"  # what normpath reads as one slash: //, /./
_path_schema = {
    "type": "string",
    "pattern": c.json_pattern(c.ABS_PATH),
    "not": {"pattern": "(?:^|/)\\.\\.(?:/|$)"},
    "description": "an absolute path without '..'",
}
c.with_schema(
    address,
    {
        "type": "string",
        "pattern": c.json_pattern(ADDRESS),
        "description": "a host name, an IPv4 or an IPv6 address (the port goes in ssh_port)",
    },
)
c.with_schema(abs_path, _path_schema)
c.with_schema(
    local_path, {"type": "string", "pattern": c.json_pattern(LOCAL_PATH), "description": "a path on this machine"}
)


def _places_pattern(places) -> str:
    return "^" + _SEP + "(?:" + "|".join(w.lstrip("/").replace("/", _SEP) for w in _spellings(places)) + ")(?:/|$)"


c.with_schema(
    private_path,
    {
        **_path_schema,
        "not": {
            "anyOf": [
                _path_schema["not"],
                {"pattern": _places_pattern(WORLD_WRITABLE + SHARED_INSIDE)},
                {"not": {"pattern": _places_pattern(ROOT_ONLY)}},
            ]
        },
        "description": "an absolute path in a place only root writes ("
        + ", ".join(ROOT_ONLY)
        + "), outside world-writable directories (/tmp, /run/lock, ...)",
    },
)
c.with_schema(
    fingerprint,
    {"type": "string", "pattern": "^(?: *[0-9A-Fa-f]){40} *$", "description": "a 40-digit hex OpenPGP fingerprint"},
)
