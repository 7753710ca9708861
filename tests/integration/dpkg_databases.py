"""dpkg databases of a test's own, in the states dpkg --audit reports, and
the audit read both ways (the snapshot's probe, dpkg itself)."""

from __future__ import annotations

import subprocess
from pathlib import Path

from robotfleet.host import apt

NATIVE = subprocess.run(["dpkg", "--print-architecture"], capture_output=True, text=True).stdout.strip()


def stanza(name, status="install ok installed", arch=None, multiarch=None, extra=()):
    lines = [f"Package: {name}", f"Status: {status}", "Priority: optional", "Maintainer: Lab <lab@example.org>", *extra]
    lines += [f"Architecture: {arch or NATIVE}"] if arch != "" else []
    lines += [f"Multi-Arch: {multiarch}"] if multiarch else []
    lines += ["Version: 1.0", "Description: a package", " with a long description"]
    return "\n".join(lines) + "\n"


def admindir(tmp_path, stanzas, info=None, journal=False, multiarch_db=True) -> Path:
    d = tmp_path / "dpkg"
    (d / "info").mkdir(parents=True)
    (d / "updates").mkdir()
    if multiarch_db:
        (d / "info" / "format").write_text("1\n")
    (d / "status").write_text("\n".join(stanzas))
    for name in info if info is not None else []:
        (d / "info" / name).write_text("/.\n")
    if journal:
        (d / "updates" / "0000").write_text(stanzas[0])
    return d


def audit_before(d: Path) -> str:
    """The probe as it was: the journal, then dpkg --audit's first lines."""
    script = (
        f"ls {d}/updates 2>/dev/null | grep -q . && echo 'dpkg journal not empty'; "
        f"dpkg --admindir={d} --audit 2>/dev/null | head -n 5"
    )
    return subprocess.run(["sh", "-c", script], capture_output=True, text=True).stdout


def audit_now(d: Path) -> str:
    return subprocess.run(["sh", "-c", apt.dpkg_audit_probe(str(d))], capture_output=True, text=True).stdout


def both_files(*names):
    return [f"{n}.{kind}" for n in names for kind in ("list", "md5sums")]


CASES = {
    "healthy": (
        [
            stanza("a"),
            stanza("b", arch="all"),
            stanza("c", "deinstall ok config-files"),
            stanza("lib", multiarch="same"),
        ],
        both_files("a", "b", f"lib:{NATIVE}"),
    ),
    "unpacked": ([stanza("a"), stanza("b", "install ok unpacked")], both_files("a", "b")),
    "half-configured": ([stanza("a", "install ok half-configured")], both_files("a")),
    "half-installed": ([stanza("a", "install ok half-installed")], both_files("a")),
    "reinstreq": ([stanza("a", "install reinstreq installed")], both_files("a")),
    "triggers pending": (
        [stanza("a", "install ok triggers-pending", extra=["Triggers-Pending: /usr/share/x"])],
        both_files("a"),
    ),
    "triggers awaited": (
        [
            stanza("a", "install ok triggers-awaited", extra=["Triggers-Awaited: b"]),
            stanza("b", "install ok triggers-pending", extra=["Triggers-Pending: /usr/share/x"]),
        ],
        both_files("a", "b"),
    ),
    "no list file": ([stanza("a"), stanza("b")], both_files("a") + ["b.md5sums"]),
    "no md5sums file": ([stanza("a")], ["a.list"]),
    "multiarch file named without its arch": ([stanza("lib", multiarch="same")], both_files("lib")),
    "unknown foreign architecture": ([stanza("a", arch="s390x")], both_files("a")),
    "no architecture": ([stanza("a", arch="")], both_files("a")),
}
