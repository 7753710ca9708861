"""Malformed-armor key files and apt's own reading of them, for the key-pin
tests (issue 17 item 1): unit tests run the apt check here (apt 2.6, gpgv),
end-to-end tests on a Debian 13 lab host (apt 3, sqv).

Two keys, a pinned one (with a signing subkey, like Docker's) and an
intruder's; a flat apt repository per key offering a fake docker-ce, its
InRelease signed by that key; key files hiding the intruder's key behind
armor quirks; and a shell script that runs the real ``apt-get update``
with a private configuration (the machine's own apt state is untouched)
and reports whether apt then offers the fake docker-ce.
"""

from __future__ import annotations

import shlex
import subprocess
from pathlib import Path

FAKE_VERSION = "6.6.6-fake"
BEGIN, END = "-----BEGIN PGP PUBLIC KEY BLOCK-----", "-----END PGP PUBLIC KEY BLOCK-----"


def gpg(home, *args, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run(["gpg", "--batch", "--homedir", str(home), *args], capture_output=True, check=True, **kwargs)


def new_key(home: Path, uid: str, with_subkey: bool = False) -> str:
    """A fresh ed25519 signing key for ``uid`` in ``home`` (mode 0700), with a
    signing subkey too when asked (Docker's key has one); its fingerprint.
    gpg starts an agent for the secret key: ``stop_agents`` ends it."""
    home.mkdir(mode=0o700, exist_ok=True)
    gpg(home, "--passphrase", "", "--pinentry-mode", "loopback", "--quick-gen-key", uid, "ed25519", "sign", "never")
    listing = gpg(home, "--with-colons", "--list-keys", uid, text=True).stdout
    fingerprint = next(line.split(":")[9] for line in listing.splitlines() if line.startswith("fpr"))
    if with_subkey:
        gpg(
            home,
            "--passphrase",
            "",
            "--pinentry-mode",
            "loopback",
            "--quick-add-key",
            fingerprint,
            "ed25519",
            "sign",
            "never",
        )
    return fingerprint


def stop_agents(under: Path) -> None:
    """Stop the gpg agents of every keyring under ``under`` (tests' temporary keyrings)."""
    for keyring in under.rglob("pubring.kbx"):
        subprocess.run(["gpgconf", "--homedir", str(keyring.parent), "--kill", "gpg-agent"], capture_output=True)


def signers(home: Path) -> tuple[dict[str, str], dict[str, str]]:
    """Fingerprints and armored public keys of "pinned" and "intruder",
    their secret keys in ``home`` (an empty directory, mode 0700)."""
    fprs = {name: new_key(home, f"{name}@example", with_subkey=name == "pinned") for name in ("pinned", "intruder")}
    return fprs, {name: gpg(home, "--armor", "--export", fpr, text=True).stdout for name, fpr in fprs.items()}


def repository(home, signer: str, where: Path) -> None:
    """A flat apt repository in ``where`` offering a fake docker-ce, InRelease signed by ``signer``."""
    where.mkdir(parents=True)
    packages = (
        f"Package: docker-ce\nVersion: 99:{FAKE_VERSION}\nArchitecture: all\n"
        "Maintainer: nobody <nobody@example.invalid>\nFilename: ./docker-ce.deb\nSize: 1\n"
        f"SHA256: {'0' * 64}\nDescription: fake\n\n"
    )
    (where / "Packages").write_text(packages)
    digest = subprocess.run(["sha256sum"], input=packages.encode(), capture_output=True, check=True).stdout.split()[0]
    release = (
        "Origin: fake\nLabel: fake\nSuite: fake\nCodename: fake\nDate: Thu, 01 Jan 2026 00:00:00 UTC\n"
        f"SHA256:\n {digest.decode()} {len(packages)} Packages\n"
    )
    (where / "Release").write_text(release)
    gpg(home, "--local-user", signer + "!", "--clearsign", "-o", str(where / "InRelease"), str(where / "Release"))


def apt_check_script(key_file: str, repo: str, work: str) -> str:
    """Shell: apt-get update against ``repo`` with ``key_file`` as Signed-By,
    everything apt keeps under the fresh directory ``work``; prints
    ``offered`` when apt-cache policy then offers the fake docker-ce, then
    ``update=<exit code>``.  APT_CONFIG is read before apt.conf.d, so the
    machine's own configuration is never read."""
    k, r, d = (shlex.quote(v) for v in (key_file, repo, work))
    options = (
        f"-oDir::Etc::SourceList=/dev/null -oDir::Etc::SourceParts={d}/sources -oDir::State::Lists={d}/lists "
        f"-oDir::Cache={d}/cache -oDir::State::status={d}/status -oDir::Etc::Preferences=/dev/null "
        f"-oDir::Etc::PreferencesParts={d}/preferences -oDir::Etc::Trusted=/dev/null "
        f"-oDir::Etc::TrustedParts={d}/parts -oDebug::NoLocking=1 -oAPT::Sandbox::User=root"
    )
    return "\n".join(
        [
            f"mkdir -p {d}/lists/partial {d}/cache/archives/partial {d}/sources {d}/parts {d}/preferences",
            f": > {d}/status",
            f"printf 'Types: deb\\nURIs: file:%s\\nSuites: ./\\nSigned-By: %s\\n' {r} {k} > {d}/sources/fake.sources",
            f'printf \'Dir::Etc::Parts "%s/parts";\\nDir::Etc::Main "/dev/null";\\n\' {d} > {d}/apt.conf',
            f"export APT_CONFIG={d}/apt.conf LC_ALL=C",
            f"apt-get {options} update > {d}/update.log 2>&1; rc=$?",
            f"apt-cache {options} policy docker-ce 2>/dev/null | grep -qF {FAKE_VERSION} && echo offered",
            "echo update=$rc",
        ]
    )


def parse_check(output: str) -> bool:
    """Whether apt offered the repository; apt-get update's exit code must agree."""
    offered = "offered" in output.split()
    assert ("update=0" in output.split()) == offered, output
    return offered


def _body(armored: str) -> list[str]:
    """The base64 lines of an armored key (between the blank line and the CRC)."""
    lines = armored.splitlines()
    start = lines.index("") + 1
    return lines[start : next(i for i in range(start, len(lines)) if lines[i].startswith("="))]


def _crc(armored: str) -> str:
    return next(line for line in armored.splitlines() if line.startswith("="))


def block(begin: str, lines: list[str], end: str) -> str:
    return "\n".join([begin, "", *lines, end]) + "\n"


def _labelled(label: str):
    return lambda p, i: p + block(f"-----BEGIN {label}-----", _body(i) + [_crc(i)], f"-----END {label}-----")


# Each: the pinned key as gpg exports it (p) plus the intruder's (i) hidden
# so that `gpg --show-keys` lists only the pinned key (gpg 2.2 and 2.4).
VARIANTS = {
    "unknown armor label": lambda p, i: p + block("-----BEGIN HIDDEN-----", _body(i), "-----END HIDDEN-----"),
    "text after the BEGIN line": lambda p, i: p + block(BEGIN + " x", _body(i) + [_crc(i)], END),
    "inside the block after its CRC line": lambda p, i: "\n".join(p.splitlines()[:-1] + _body(i) + [END]) + "\n",
    "PGP SIGNATURE label": _labelled("PGP SIGNATURE"),
    "PGP MESSAGE label": _labelled("PGP MESSAGE"),
    "signed-message header, no END": lambda p, i: (
        p + "\n".join(["-----BEGIN PGP SIGNED MESSAGE-----", "Hash: SHA256", "", *_body(i)]) + "\n"
    ),
    "indented BEGIN line": lambda p, i: p + block(" " + BEGIN, _body(i) + [_crc(i)], END),
}
# Those apt 2.6 (awk+base64 dearmoring, then gpgv) reads the hidden key from,
# and those Debian 13's sqv 1.3 does (seen on a lab host).
APT26_TRUSTS_HIDDEN = sorted(set(VARIANTS) - {"indented BEGIN line"})
SQV_TRUSTS_HIDDEN = ["PGP SIGNATURE label", "PGP MESSAGE label", "indented BEGIN line"]


def variant(name: str, armored: dict[str, str]) -> bytes:
    return VARIANTS[name](armored["pinned"], armored["intruder"]).encode()


def bad_crc(armored: dict[str, str]) -> bytes:
    """A second block with a wrong CRC: gpg reads nothing, apt 2.6 and sqv trust both keys."""
    return (armored["pinned"] + block(BEGIN, _body(armored["intruder"]) + ["=AAAA"], END)).encode()
