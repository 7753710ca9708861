"""Kinds of values several roles' settings share: addresses, URLs, paths on
a host, paths on this machine, OpenPGP fingerprints.  Each is a checker
(engine/checks.py) carrying its JSON Schema."""

from __future__ import annotations

import ipaddress
import posixpath
import re

from engine import checks as c

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


def canonical(path: str) -> str:
    """``path`` normalized, with the known aliases of system directories
    resolved (as the host would resolve them)."""
    normal = "/" + posixpath.normpath(path).lstrip("/")
    changed = True
    while changed:
        changed = False
        for alias, target in ALIASES:
            if normal == alias or normal.startswith(alias + "/"):
                normal = target + normal[len(alias):]
                changed = True
    return normal
_DOTTED_NUMBERS = re.compile(r"[0-9.]+")
_SCOPE = re.compile(r"[A-Za-z0-9_.-]{1,15}", re.ASCII)
_HOST_PORT = re.compile(r"([^:\s\[\]]+|\[[^\]]*\]):([0-9]+)")
_DNS_NAME = re.compile(r"(?=.{1,253}\.?$)[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?(?:\.[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?)*\.?", re.ASCII)

url = c.string(URL, URL_WHAT)
user_name = c.string(c.USER_NAME, "a user name")
package_name = c.string(r"[a-z0-9][a-z0-9.+-]+", "a package name")
apt_version = c.string(r"[0-9][0-9A-Za-z.+~:-]*", "an apt version string")
file_name = c.string(r"[A-Za-z0-9][A-Za-z0-9_.-]*", "a file name")


def address(value):
    """A host name, an IPv4 or an IPv6 address (what SSH connects to)."""
    if not isinstance(value, str):
        return [("", c.expected_string(value, "a host name or an IP address"))]
    try:
        parsed = ipaddress.ip_address(value)
    except ValueError:
        pass
    else:
        # Python takes anything after % as an IPv6 scope, newlines included.
        scope = getattr(parsed, "scope_id", None)
        if scope is not None and not _SCOPE.fullmatch(scope):
            return [("", f"expected an IPv6 scope of letters, digits and . _ - after %, got {c.shown(value)}")]
        return []
    if value.startswith("[") and value.endswith("]"):
        return [("", f"expected an IPv6 address without brackets, got {c.shown(value)}")]
    host_port = _HOST_PORT.fullmatch(value)
    if host_port:
        return [("", f"expected a host name or an IP address, got {c.shown(value)}; put the port in ssh_port: {host_port.group(2)}")]
    if _DOTTED_NUMBERS.fullmatch(value):
        return [("", f"{c.shown(value)} is not a valid IPv4 address")]
    if not _DNS_NAME.fullmatch(value) or value.rstrip(".").rsplit(".", 1)[-1].isdigit():
        return [("", f"expected a host name or an IP address, got {c.shown(value)}")]
    return []


def local_path(value):
    """A file on the operator's machine (never sent to a host): any path
    that prints as itself (no control or direction-changing characters)."""
    if not isinstance(value, str):
        return [("", c.expected_string(value, "a path on this machine"))]
    if not value or not value.isprintable():
        return [("", f"expected a path on this machine of printable characters, got {c.shown(value)}")]
    return []


def abs_path(value):
    problems = c.string(c.ABS_PATH, "an absolute path")(value)
    if not problems and ".." in value.split("/"):
        return [("", f"paths must not contain '..', got {c.shown(value)}")]
    return problems


def private_path(value):
    """A path root creates, chmods or writes: not in a world-writable directory."""
    problems = abs_path(value)
    if problems:
        return problems
    normal = canonical(value)
    for shared in WORLD_WRITABLE:
        if normal == shared or normal.startswith(shared + "/"):
            return [("", f"{c.shown(value)} is in the world-writable {shared}; use a directory only root can write (e.g. under /var/lib)")]
    return []


_FINGERPRINT = c.string(r"[0-9A-Fa-f]{40}", "a 40-digit hex OpenPGP fingerprint")


def fingerprint(value):
    return _FINGERPRINT(value.replace(" ", "") if isinstance(value, str) else value)


def normal_fingerprint(value: str | None) -> str | None:
    """A fingerprint as gpg prints it: no spaces, upper case."""
    return value.replace(" ", "").upper() if value else None


def _spellings() -> list[str]:
    """Every way to write a world-writable directory, aliases included (for
    the editors' schema, which cannot resolve them)."""
    found = set(WORLD_WRITABLE)
    while True:
        more = {alias + path[len(target):] for path in found for alias, target in ALIASES
                if path == target or path.startswith(target + "/")}
        if more <= found:
            return sorted(found)
        found |= more


_path_schema = {"type": "string", "pattern": c.json_pattern(c.ABS_PATH), "description": "an absolute path without '..'"}
c.with_schema(address, {"type": "string", "description": "a host name, an IPv4 or an IPv6 address (the port goes in ssh_port)"})
c.with_schema(abs_path, _path_schema)
c.with_schema(local_path, {"type": "string", "description": "a path on this machine"})
c.with_schema(private_path, {
    **_path_schema,
    "not": {"pattern": "^/+(?:" + "|".join(w.lstrip("/") for w in _spellings()) + ")(?:/|$)"},
    "description": "an absolute path outside world-writable directories (/tmp, /var/tmp, /dev/shm, ...)",
})
c.with_schema(fingerprint, {"type": "string", "pattern": "^(?: *[0-9A-Fa-f]){40} *$", "description": "a 40-digit hex OpenPGP fingerprint"})
