"""Registry login on the robot, only when the credentials changed: the
robot keeps a salted PBKDF2 of them (0600), never the password."""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import shlex

from pyinfra import host

from robotfleet.host import operations

DOCKER_CONFIG_DIR = "/root/.docker"
DOCKER_HUB_NAMES = ("docker.io", "index.docker.io", "registry-1.docker.io")
LOGIN_ITERATIONS = 100_000


def registry_config_key(registry: str) -> str:
    """The key `docker login` stores a registry's credentials under."""
    return "https://index.docker.io/v1/" if registry in DOCKER_HUB_NAMES else registry


def login_record_path(registry: str) -> str:
    name = hashlib.sha256(registry_config_key(registry).encode()).hexdigest()[:16]
    return f"{DOCKER_CONFIG_DIR}/robotprov-login-{name}"


def credentials_record(registry: str, username: str, password: str, salt: str | None = None) -> str:
    """What the robot keeps (0600) to know which credentials it is logged in
    with: a salted PBKDF2 of (registry, username, password), never the password."""
    salt = salt or os.urandom(16).hex()
    secret = json.dumps([registry_config_key(registry), username, password]).encode()
    digest = hashlib.pbkdf2_hmac("sha256", secret, bytes.fromhex(salt), LOGIN_ITERATIONS).hex()
    return f"pbkdf2-sha256:{LOGIN_ITERATIONS}:{salt}:{digest}"


def credentials_match(stored: str, registry: str, username: str, password: str) -> bool:
    parts = stored.strip().split(":")
    if len(parts) != 4 or parts[0] != "pbkdf2-sha256" or parts[1] != str(LOGIN_ITERATIONS):
        return False
    try:
        wanted = credentials_record(registry, username, password, salt=parts[2])
    except ValueError:  # not a hex salt
        return False
    return hmac.compare_digest(wanted, stored.strip())


def registry_probe(registry: str) -> str:
    """The stored credentials record, if Docker still holds a login there."""
    q = shlex.quote
    return (
        f"grep -qF {q(json.dumps(registry_config_key(registry)))} {DOCKER_CONFIG_DIR}/config.json"
        f" && cat {q(login_record_path(registry))}"
    )


@operations.operation()
def registry_login(registry: str, username: str, password: str, stored: str):
    """Log in unless the robot's record says it is logged in with exactly
    these credentials (a changed password is applied).  The record and the
    password go over stdin, so neither is on a command line."""
    if credentials_match(stored, registry, username, password):
        host.noop(f"logged in to {registry}")
        return
    q = shlex.quote
    script = (
        "set -e\n"
        "read -r record\n"
        f"docker login {q(registry)} --username {q(username)} --password-stdin >/dev/null\n"
        "umask 077\n"
        f"path={q(login_record_path(registry))}\n"
        'tmp=$(mktemp "$(dirname "$path")/.robotprov.XXXXXX")\n'
        "trap 'rm -f \"$tmp\"' EXIT\n"
        'printf "%s\\n" "$record" > "$tmp"\n'
        'sync "$tmp"\n'
        'mv -fT "$tmp" "$path"\n'
        "trap - EXIT\n"
    )
    yield operations.shell(script, stdin=[credentials_record(registry, username, password), password])
