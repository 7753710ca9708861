"""A third-party apt repository pinned to its signing key (Docker's,
NVIDIA's): the key, checked against its fingerprint before it is installed,
a deb822 source that trusts only that key (Signed-By), and apt update when
either changed, waiting for the apt lock like every other apt call.

The key file must hold exactly one primary key, the pinned one: apt trusts
every key of a Signed-By keyring, so a second key beside the pinned one
would sign packages too.  A keyring on the host that holds more than one key
is removed whatever the download gives (fail closed)."""

from __future__ import annotations

import shlex
from dataclasses import dataclass

from pyinfra import host
from pyinfra.operations.util import any_changed

from engine.host import apt, operations
from engine.host.snapshot import Snapshot, SnapshotQuery

KEYRING_DIR = "/etc/apt/keyrings"
SOURCES_DIR = "/etc/apt/sources.list.d"
# Primary keys only (pub, or sec if someone served a secret key): the fpr
# record that follows each; subkeys' fingerprints are not primaries.
_PRIMARIES_AWK = "awk -F: '$1==\"pub\"||$1==\"sec\"{p=1;next} $1==\"fpr\"&&p{print $10;p=0} $1==\"sub\"||$1==\"ssb\"{p=0}'"


@dataclass(frozen=True)
class Repository:
    """One pinned repository as a role declares it."""

    what: str  # named in messages: "Docker", "NVIDIA"
    key_url: str
    key_path: str
    fingerprint: str | None  # None: no pin (a mirror's own key, checked by sha256 if given)
    fingerprint_setting: str  # the setting that pins it, named in messages
    sources_name: str  # /etc/apt/sources.list.d/<name>.sources
    sources: str  # the deb822 text (see ``deb822``)
    probe: str  # name of the snapshot probe listing the installed key's primary keys
    sha256: str | None = None
    sha256_setting: str = "sha256"

    @property
    def sources_path(self) -> str:
        return f"{SOURCES_DIR}/{self.sources_name}.sources"


def deb822(owner: str, uris: str, suites: str, signed_by: str, components: str | None = None,
           architectures: str | None = None) -> str:
    lines = [f"# Managed by the robot fleet provisioner ({owner}).", "Types: deb", f"URIs: {uris}", f"Suites: {suites}"]
    if components:
        lines.append(f"Components: {components}")
    if architectures:
        lines.append(f"Architectures: {architectures}")
    lines.append(f"Signed-By: {signed_by}")
    return "\n".join(lines) + "\n"


def primary_fingerprints(path: str) -> str:
    """Shell pipeline printing the primary-key fingerprints in key file
    ``path`` (a shell word, already quoted), one a line, using the throwaway
    GNUPGHOME ``$h``."""
    return f"GNUPGHOME=$h gpg --batch --show-keys --with-colons {path} 2>/dev/null | {_PRIMARIES_AWK}"


def fingerprints_probe(path: str) -> str:
    p = shlex.quote(path)
    return f'[ -f {p} ] && command -v gpg >/dev/null && h=$(mktemp -d) && {primary_fingerprints(p)}; rm -rf "$h"'


def key_script(repo: Repository) -> str:
    """Fetch the key to a temp file beside its place, check it, and only
    then move it in place.  Values reach the messages through shell
    variables, never as code."""
    q = shlex.quote
    lines = [
        "set -e",
        f"dest={q(repo.key_path)}",
        f"url={q(repo.key_url)}",
        f"what={q(repo.what + ' apt key')}",
        f"setting={q(repo.fingerprint_setting)}",
        f"sha_setting={q(repo.sha256_setting)}",
        'mkdir -p "$(dirname "$dest")"',
        'tmp=$(mktemp "$(dirname "$dest")/.robotprov.XXXXXX")',
        "h=$(mktemp -d)",
        "trap 'rm -f \"$tmp\"; rm -rf \"$h\"' EXIT",
    ]
    if repo.fingerprint:
        lines += [
            f"pin={q(repo.fingerprint)}",
            'if [ -f "$dest" ] && [ "$(' + primary_fingerprints('"$dest"') + ' | wc -l)" -gt 1 ]; then',
            '  rm -f "$dest"; echo "$dest held more than one key; removed" >&2',
            "fi",
        ]
    lines.append(
        'curl -fsSL --retry 3 --connect-timeout 20 "$url" -o "$tmp" || '
        '{ echo "cannot download the $what from $url" >&2; exit 1; }'
    )
    if repo.sha256:
        lines += [
            f"want={q(repo.sha256)}",
            'got=$(sha256sum < "$tmp" | cut -d" " -f1); '
            '[ "$got" = "$want" ] || { echo "$what from $url: sha256 $got does not match '
            '$sha_setting $want; key not installed" >&2; exit 1; }',
        ]
    if repo.fingerprint:
        lines += [
            "fprs=$(" + primary_fingerprints('"$tmp"') + ")",
            'count=$(printf "%s\\n" "$fprs" | grep -c . || true)',
            'printf "%s\\n" "$fprs" | grep -qx "$pin" || { echo "$what from $url: fingerprint '
            '$(echo $fprs) does not match $setting $pin; key not installed" >&2; exit 1; }',
            '[ "$count" -eq 1 ] || { echo "$what from $url: holds $count keys ($(echo $fprs)); '
            'only $setting $pin may be in it; key not installed" >&2; exit 1; }',
        ]
    lines += ['chmod 644 "$tmp"', 'mv -fT "$tmp" "$dest"']
    return "\n".join(lines)


def only_pinned(probe_output: str, fingerprint: str) -> bool:
    return probe_output.split() == [fingerprint]


def key_is_current(repo: Repository, snap: Snapshot) -> bool:
    """In place, 0644, and (when pinned) holding exactly the pinned key."""
    current = snap.files.get(repo.key_path)
    if current is None or current.kind != "file" or current.mode != "644":
        return False
    if repo.sha256 and current.sha256 != repo.sha256:
        return False
    return not repo.fingerprint or only_pinned(snap.probes.get(repo.probe, ""), repo.fingerprint)


def declare_reads(repo: Repository, query: SnapshotQuery) -> None:
    query.files |= {KEYRING_DIR, repo.key_path, repo.sources_path}
    if repo.fingerprint:
        query.probes[repo.probe] = fingerprints_probe(repo.key_path)


@operations.operation()
def pinned_key(repo: Repository, up_to_date: bool):
    if up_to_date:
        host.noop(f"{repo.key_path} holds exactly the pinned key" if repo.fingerprint else f"{repo.key_path} is in place")
        return
    yield operations.shell(key_script(repo))


def set_up(repo: Repository, snap: Snapshot, *also_changed) -> None:
    """The keyring directory, the key, the source, and apt update when any
    of them (or ``also_changed``, e.g. removed legacy files) changed."""
    operations.directory(name=f"apt keyring directory {KEYRING_DIR}", path=KEYRING_DIR, current=snap.files.get(KEYRING_DIR))
    key = pinned_key(
        name=f"Download {repo.what}'s apt key and check it is exactly the pinned key",
        repo=repo,
        up_to_date=key_is_current(repo, snap),
    )
    source = operations.file(
        name=f"Write the {repo.what} apt source",
        path=repo.sources_path,
        content=repo.sources,
        current=snap.files.get(repo.sources_path),
    )
    apt.apt_update(name=f"apt update for the {repo.what} repository", _if=any_changed(key, source, *also_changed))
