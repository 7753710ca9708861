"""Registry credentials, each for its own registry (as Docker's config.json
``auths``): payload_registry_auths maps a registry to where its username and
password come from on this machine (environment variables, or files outside
the checkout), never the values themselves.  The single-registry settings
(payload_registry_username_env/_password_env) are the primary registry's
(the first service's image) when payload_registry_auths does not name it.

A credential goes only to the registry it is configured for: `docker login`
on the robot (pull), or the operator side's registry client (push,
roles/payload/registry.py), which also sends it to a token realm only over
HTTPS on that registry's own host (or the same plain-HTTP host the fleet
marks insecure, or this machine's), to a realm listed in ``token_realms``,
and never again after a redirect to another host.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import roles.payload.payloadctl.imageref as imageref
import roles.payload.services as services
from robotfleet import CHECKOUT
from robotfleet import checkers as c
from robotfleet import value_kinds as v

DOCKER_HUB = ("docker.io", "index.docker.io", "registry-1.docker.io")
# Docker Hub's registry sends its clients to its token service on another host.
KNOWN_REALMS = {"docker.io": ("https://auth.docker.io/token",)}
REGISTRY = r"[A-Za-z0-9][A-Za-z0-9.-]*(?::[0-9]+)?"
_SOURCE = r"(?:/|~/)" + v.LOCAL_PATH
_HTTPS_URL = "https" + v.URL[len("https?") :]


def registry_key(registry: str) -> str:
    """The name credentials are kept under: Docker Hub's names are one."""
    return "docker.io" if registry in DOCKER_HUB else registry


@dataclass(frozen=True)
class Credentials:
    """A username and password for ``registry`` only; ``realms``: the token
    services besides the registry's own host it may be sent to."""

    registry: str
    username: str
    password: str = field(repr=False)
    realms: tuple[str, ...] = ()


class CredentialError(Exception):
    """A configured credential cannot be read; the message is one line."""


# -- the setting -----------------------------------------------------------

_env = c.string(c.ENV_NAME, "an environment variable name")
local_file = c.string(_SOURCE, "an absolute path (or ~/...) on this machine")
FIELDS = {
    "username_env": _env,
    "username_file": local_file,
    "password_env": _env,
    "password_file": local_file,
    "token_realms": c.list_of(c.string(_HTTPS_URL, "an https URL"), unique=True),
}


def auth_entry(value):
    if not isinstance(value, dict):
        return [
            (
                "",
                f"expected a mapping with username_env or username_file and password_env or password_file, "
                f"got {c.describe(value)}",
            )
        ]
    problems = []
    for key, item in value.items():
        if key not in FIELDS:
            problems.append((f".{c.key_name(key)}", "unknown field" + c.did_you_mean(str(key), FIELDS)))
        else:
            problems += [(f".{key}{sub}", msg) for sub, msg in FIELDS[key](item)]
    for what in ("username", "password"):
        given = [k for k in (f"{what}_env", f"{what}_file") if k in value]
        if len(given) != 1:
            problems.append(
                (
                    "",
                    f"give one of {what}_env (an environment variable) or {what}_file "
                    "(a file outside the checkout), not the value itself",
                )
            )
    return problems


c.with_schema(
    auth_entry,
    {
        "type": "object",
        "properties": {key: check.schema for key, check in FIELDS.items()},
        "additionalProperties": False,
        "allOf": [
            {"oneOf": [{"required": [f"{what}_env"]}, {"required": [f"{what}_file"]}]}
            for what in ("username", "password")
        ],
        "description": "where this registry's username and password come from on this machine",
    },
)
auths = c.mapping_of(c.string(REGISTRY, "a registry host[:port]"), auth_entry)


def files_in_checkout(value) -> list[c.Problem]:
    """Credential files must stay out of the repository (it is shared, pushed, diffed)."""
    problems = []
    for registry, entry in (value or {}).items() if isinstance(value, dict) else ():
        for key in ("username_file", "password_file"):
            path = entry.get(key) if isinstance(entry, dict) else None
            if isinstance(path, str) and inside_checkout(path):
                problems.append(
                    (
                        f"payload_registry_auths.{c.key_name(registry)}.{key}",
                        f"{c.shown(path)} is inside the checkout {CHECKOUT}; keep credentials outside the "
                        "repository (e.g. ~/.config/robotfleet/)",
                    )
                )
    return problems


def inside_checkout(path: str) -> bool:
    resolved = Path(os.path.expanduser(path)).resolve()
    return resolved == CHECKOUT or CHECKOUT in resolved.parents


# -- reading them ----------------------------------------------------------


def primary_registry(data) -> str | None:
    """The registry of the first service's image (the single-registry settings' one)."""
    refs = services.images(data)
    try:
        return imageref.parse(refs[0]).registry if refs else None
    except ValueError:
        return None


def registries(data) -> list[str]:
    """Every registry the payload's images come from, the primary's first."""
    found = []
    for ref in services.images(data):
        try:
            found.append(registry_key(imageref.parse(ref).registry))
        except ValueError:
            continue
    return list(dict.fromkeys(found))


def entries(data) -> dict[str, dict]:
    """registry -> where its credentials come from: payload_registry_auths,
    and the single-registry settings for the primary registry."""
    found = {registry_key(k): dict(e) for k, e in (data.get("payload_registry_auths") or {}).items()}
    primary = primary_registry(data)
    if primary and registry_key(primary) not in found:
        found[registry_key(primary)] = {
            "username_env": data.get("payload_registry_username_env"),
            "password_env": data.get("payload_registry_password_env"),
            "default": True,
        }
    return found


def _read(entry: dict, what: str, registry: str) -> str | None:
    if not entry.get(f"{what}_file"):
        name = entry.get(f"{what}_env")
        return (os.environ.get(name) or None) if name else None
    path = os.path.expanduser(entry[f"{what}_file"])
    try:
        with open(path, encoding="utf-8") as handle:
            return handle.read().rstrip("\r\n") or None
    except (OSError, UnicodeDecodeError) as error:
        raise CredentialError(
            f"payload_registry_auths.{registry}.{what}_file: cannot read {path}: "
            f"{getattr(error, 'strerror', None) or error}"
        ) from None


def lookup(data, registry: str) -> Credentials | None:
    """The credentials configured for ``registry``, or None (anonymous).  A
    registry payload_registry_auths names must have them (CredentialError);
    the primary registry's default environment variables may be unset."""
    key = registry_key(registry)
    entry = entries(data).get(key)
    if entry is None:
        return None
    username, password = _read(entry, "username", key), _read(entry, "password", key)
    if not (username and password):
        if entry.get("default"):
            return None
        missing = [
            f"{w}_env {entry[w + '_env']} is not set" if entry.get(f"{w}_env") else f"{w}_file is empty"
            for w, got in (("username", username), ("password", password))
            if not got
        ]
        raise CredentialError(f"payload_registry_auths.{key}: " + " and ".join(missing))
    return Credentials(key, username, password, KNOWN_REALMS.get(key, ()) + tuple(entry.get("token_realms") or ()))


def secrets(data) -> list[str]:
    """Every registry password configured for this host (masked in output)."""
    found = []
    for registry in entries(data):
        try:
            credentials = lookup(data, registry)
        except CredentialError:
            continue
        if credentials:
            found.append(credentials.password)
    return found
