"""A third-party apt repository pinned to its signing key (Docker's,
NVIDIA's): the key, checked against its fingerprint before it is installed,
a deb822 source that trusts only that key (Signed-By), and apt update when
either changed, waiting for the apt lock like every other apt call.

apt trusts every key of a Signed-By keyring, and gpg, apt 2.6 (gpgv, after
its own awk+base64 dearmoring) and apt 3's sqv each parse an armored file
their own way: a file gpg lists as only the pinned key can carry a block the
other two read and trust (behind an armor line gpg skips, after a CRC line,
...).  So the downloaded bytes are never installed.  They are imported into
a throwaway keyring, which must hold exactly one primary key, the pinned
one, and the file installed is gpg's own export of that key: armored when
the key path ends in .asc (apt picks the format by extension), binary
otherwise.  The snapshot probe checks the installed file is byte for byte
that export; anything else is replaced, and a key file that is not exactly
that is removed whatever the download gives (fail closed).

Without a pinned fingerprint (``docker_apt_key_fingerprint: null``) the file
is installed as downloaded, checked only by its sha256 if one is set."""

from __future__ import annotations

import shlex
from dataclasses import dataclass

from pyinfra import host
from pyinfra.operations.util import any_changed

from robotfleet.host import apt, operations
from robotfleet.host.snapshot import Snapshot, SnapshotQuery

KEYRING_DIR = "/etc/apt/keyrings"
SOURCES_DIR = "/etc/apt/sources.list.d"
# Primary keys only (pub, or sec if someone served a secret key): the fpr
# record that follows each; subkeys' fingerprints are not primaries.
_PRIMARIES_AWK = 'awk -F: \'$1=="pub"||$1=="sec"{p=1;next} $1=="fpr"&&p{print $10;p=0} $1=="sub"||$1=="ssb"{p=0}\''


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


def deb822(
    owner: str, uris: str, suites: str, signed_by: str, components: str | None = None, architectures: str | None = None
) -> str:
    lines = [f"# Managed by the robot fleet provisioner ({owner}).", "Types: deb", f"URIs: {uris}", f"Suites: {suites}"]
    if components:
        lines.append(f"Components: {components}")
    if architectures:
        lines.append(f"Architectures: {architectures}")
    lines.append(f"Signed-By: {signed_by}")
    return "\n".join(lines) + "\n"


def armored(key_path: str) -> bool:
    """apt reads a Signed-By file as armored by its extension (.asc); any
    other name is installed binary, which apt 2.6 and sqv both read as is."""
    return key_path.endswith(".asc")


CANONICAL = "canonical"  # the probe's word for "the file is gpg's export of the pinned key alone"


def _canonical_function(key_path: str) -> str:
    """Shell function ``canonical FILE KEYRING OUT``: import FILE into the
    new throwaway keyring KEYRING, write gpg's own export of the pinned key
    (``$pin``) to OUT, and print the primary fingerprints the keyring got.
    What gpg did not import (a block behind an armor line gpg skips) is
    not in OUT, whatever apt or sqv would have made of it."""
    export = "--armor --export" if armored(key_path) else "--export"
    gpg = 'GNUPGHOME="$2" gpg --batch --no-autostart'
    return (
        "canonical() {\n"
        '  mkdir -m 700 "$2" || return 0\n'
        f'  {gpg} --quiet --import "$1" >/dev/null 2>&1 || true\n'
        f'  {gpg} {export} "$pin" > "$3" 2>/dev/null || true\n'
        f"  {gpg} --with-colons --list-keys 2>/dev/null | {_PRIMARIES_AWK}\n"
        "}"
    )


def key_probe(key_path: str, fingerprint: str | None) -> str:
    """Snapshot probe: the primary fingerprints in the installed key file
    (as gpg imports it), then ``canonical`` when the file is byte for byte
    gpg's export of the pinned key alone (the form ``key_script``
    installs).  Read-only: gpg works in a throwaway keyring."""
    if not fingerprint:
        return "true"
    p = shlex.quote(key_path)
    return (
        f"[ -f {p} ] && command -v gpg >/dev/null && h=$(mktemp -d) && {{\n"
        f"pin={shlex.quote(fingerprint)}\n{_canonical_function(key_path)}\n"
        f'canonical {p} "$h/k" "$h/export"\n'
        f'[ -s "$h/export" ] && cmp -s "$h/export" {p} && echo {CANONICAL}\n'
        '}; rm -rf "$h"'
    )


def key_script(repo: Repository) -> str:
    """Fetch the key, check it, and only then move it in place (a temp file
    beside it, chmod 644, mv).  With a pinned fingerprint the downloaded
    bytes are never installed: they are imported into a throwaway keyring,
    which must then hold exactly one primary key, the pinned one, and what
    is installed is gpg's own export of that key (armored for a .asc path,
    binary otherwise).  Values reach the messages through shell variables,
    never as code."""
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
        'trap \'rm -f "$tmp"; rm -rf "$h"\' EXIT',
    ]
    download = '"$h/download"' if repo.fingerprint else '"$tmp"'
    if repo.fingerprint:
        # Fail closed: a key file that may hold more than gpg sees (several
        # keys, or not gpg's own export of its one key: a block apt reads and
        # gpg skips) goes now, so it is not trusted while the download fails.
        # gpg's clean export of one other key stays until a download replaces
        # it: a mistyped pin must not take the robot's working key away.
        export = "--armor --export" if armored(repo.key_path) else "--export"
        lines += [
            f"pin={q(repo.fingerprint)}",
            _canonical_function(repo.key_path),
            'if [ -f "$dest" ]; then',
            '  old=$(canonical "$dest" "$h/installed" "$h/installed.key")',
            '  if [ "$(printf "%s\\n" "$old" | grep -c .)" -gt 1 ]; then',
            '    rm -f "$dest"; echo "$dest held more than one key ($(echo $old)); removed" >&2',
            "  else",
            '    [ -z "$old" ] || [ "$old" = "$pin" ] || '
            f'GNUPGHOME="$h/installed" gpg --batch --no-autostart {export} "$old" > "$h/installed.key" '
            "2>/dev/null || true",
            '    if [ -z "$old" ] || ! cmp -s "$h/installed.key" "$dest"; then',
            '      rm -f "$dest"; echo "$dest is not exactly the pinned key as gpg exports it ($setting $pin); '
            'removed" >&2',
            "    fi",
            "  fi",
            "fi",
        ]
    lines.append(
        f'curl -fsSL --retry 3 --connect-timeout 20 "$url" -o {download} || '
        '{ echo "cannot download the $what from $url" >&2; exit 1; }'
    )
    if repo.sha256:
        lines += [
            f"want={q(repo.sha256)}",
            f'got=$(sha256sum < {download} | cut -d" " -f1); '
            '[ "$got" = "$want" ] || { echo "$what from $url: sha256 $got does not match '
            '$sha_setting $want; key not installed" >&2; exit 1; }',
        ]
    if repo.fingerprint:
        lines += [
            'fprs=$(canonical "$h/download" "$h/new" "$tmp")',
            'count=$(printf "%s\\n" "$fprs" | grep -c . || true)',
            "listed=$(echo $fprs)",
            'printf "%s\\n" "$fprs" | grep -qx "$pin" || { echo "$what from $url: fingerprint '
            '${listed:-(none: no key gpg can read)} does not match $setting $pin; key not installed" >&2; exit 1; }',
            '[ "$count" -eq 1 ] || { echo "$what from $url: holds $count keys ($listed); '
            'only $setting $pin may be in it; key not installed" >&2; exit 1; }',
            '[ -s "$tmp" ] || { echo "$what from $url: gpg exported nothing for $setting $pin; '
            'key not installed" >&2; exit 1; }',
        ]
    lines += ['chmod 644 "$tmp"', 'mv -fT "$tmp" "$dest"']
    return "\n".join(lines)


@dataclass(frozen=True)
class InstalledKey:
    """What ``key_probe`` found in the installed key file."""

    fingerprints: tuple[str, ...]  # primary keys, as gpg imports the file
    canonical: bool  # byte for byte gpg's export of the pinned key alone


def installed_key(probe_output: str) -> InstalledKey:
    words = probe_output.split()
    return InstalledKey(tuple(w for w in words if w != CANONICAL), CANONICAL in words)


def key_is_current(repo: Repository, snap: Snapshot) -> bool:
    """In place, 0644, and (when pinned) exactly what ``key_script``
    installs: gpg's export of the pinned key alone.  A file gpg lists as the
    pinned key but that differs from that form (a block apt reads and gpg
    skips) is not current and is replaced.  Unpinned, the sha256 if set."""
    current = snap.files.get(repo.key_path)
    if current is None or current.kind != "file" or current.mode != "644":
        return False
    if repo.fingerprint:
        key = installed_key(snap.probes.get(repo.probe, ""))
        return key.canonical and key.fingerprints == (repo.fingerprint,)
    return not repo.sha256 or current.sha256 == repo.sha256


def declare_reads(repo: Repository, query: SnapshotQuery) -> None:
    query.files |= {KEYRING_DIR, repo.key_path, repo.sources_path}
    if repo.fingerprint:
        query.probes[repo.probe] = key_probe(repo.key_path, repo.fingerprint)


@operations.operation()
def pinned_key(repo: Repository, up_to_date: bool):
    if up_to_date:
        host.noop(
            f"{repo.key_path} is exactly the pinned key as gpg exports it"
            if repo.fingerprint
            else f"{repo.key_path} is in place"
        )
        return
    yield operations.shell(key_script(repo))


def set_up(repo: Repository, snap: Snapshot, *also_changed) -> None:
    """The keyring directory, the key, the source, and apt update when any
    of them (or ``also_changed``, e.g. removed legacy files) changed."""
    operations.directory(
        name=f"apt keyring directory {KEYRING_DIR}", path=KEYRING_DIR, current=snap.files.get(KEYRING_DIR)
    )
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
