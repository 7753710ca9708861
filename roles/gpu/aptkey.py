"""An apt signing key pinned by fingerprint: the keyring must hold exactly one
primary key, the pinned one, and nothing else.

Not GPU-specific (the docker role's key pin can move here): a key file that
holds the expected key *and* another primary key would let the other key
sign the repository, so "contains the fingerprint" is not enough."""

from __future__ import annotations

import shlex

# Primary keys only (pub, or sec if someone served a secret key): the fpr
# record that follows each; subkeys' fingerprints are not primaries.
_PRIMARIES_AWK = "awk -F: '$1==\"pub\"||$1==\"sec\"{p=1;next} $1==\"fpr\"&&p{print $10;p=0} $1==\"sub\"||$1==\"ssb\"{p=0}'"


def primary_fingerprints(path: str) -> str:
    """Shell pipeline printing the primary-key fingerprints in key file
    ``path`` (a shell word, already quoted), one per line, using the
    throwaway GNUPGHOME ``$h``."""
    return f"GNUPGHOME=$h gpg --batch --show-keys --with-colons {path} 2>/dev/null | {_PRIMARIES_AWK}"


def fingerprints_probe(path: str) -> str:
    """Snapshot probe: the primary fingerprints of the installed key file."""
    p = shlex.quote(path)
    return f'[ -f {p} ] && command -v gpg >/dev/null && h=$(mktemp -d) && {primary_fingerprints(p)}; rm -rf "$h"'


def only_pinned(probe_output: str, fingerprint: str) -> bool:
    return probe_output.split() == [fingerprint]


def download_script(url: str, dest: str, fingerprint: str, what: str, setting: str) -> str:
    """Fetch the key to a temp file beside ``dest``, require exactly one
    primary key with ``fingerprint``, and only then move it in place.  A
    mismatch leaves nothing behind and says which setting pins it."""
    q = shlex.quote
    mismatch = f"{what} key from {url}: primary keys [$(echo $fprs)] are not exactly the pinned {setting} {fingerprint}; key not installed"
    return "\n".join([
        "set -e",
        f"dest={q(dest)}",
        'mkdir -p "$(dirname "$dest")"',
        'tmp=$(mktemp "$(dirname "$dest")/.robotprov.XXXXXX")',
        "h=$(mktemp -d)",
        "trap 'rm -f \"$tmp\"; rm -rf \"$h\"' EXIT",
        f"curl -fsSL --retry 3 --connect-timeout 20 {q(url)} -o \"$tmp\" || "
        f"{{ echo {q(f'cannot download the {what} key from {url}')} >&2; exit 1; }}",
        "fprs=$(" + primary_fingerprints('"$tmp"') + ")",
        f'[ "$fprs" = {q(fingerprint)} ] || {{ echo "{mismatch}" >&2; exit 1; }}',
        'chmod 644 "$tmp"',
        'mv -f "$tmp" "$dest"',
    ])
