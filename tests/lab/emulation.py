"""arm64 programs on this amd64 machine: Debian's qemu-user, registered with
the kernel's binfmt_misc.

Which qemu: Debian 13's (qemu-user 10.0, fetched once from the Debian
archive into .lab/cache/qemu/; its emulator binaries are static).  Debian
12's qemu-user-static 7.2 cannot boot the arm64 host: systemd 257 spawns
every unit through posix_spawn(CLONE_INTO_CGROUP), which qemu 7.2 fails with
EINVAL ("Failed to spawn executor: Invalid argument"); qemu 10 fails it in a
way systemd falls back from.

Which flags (binfmt_misc's, Documentation/admin-guide/binfmt-misc.rst):
  F  fix-binary: the kernel opens the emulator once, at registration, so
     containers run arm64 programs without an emulator inside;
  O  open-binary: the kernel hands qemu the program as an open file, so a
     program started from a close-on-exec descriptor (systemd starts
     systemd-executor as /proc/self/fd/N) still loads (without O every unit
     exits 1: qemu reopens the path, which is gone);
  C  credentials (implies O): setuid programs (sudo) get their owner's
     rights, as they would on a real robot;
  P  preserve argv[0] (Debian's qemu-binfmt "-P" convention).
Debian's own line (usr/share/qemu/binfmt.d/qemu-aarch64.conf) gives the magic
and mask; the interpreter is the cached binary and C is added.  The entry is
kernel-wide (all containers on this machine): a registration without these
flags or with another emulator is replaced.  Every failure is one line.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from pathlib import Path

from .engine import LAB_DIR, LabError

BINFMT_DIR = Path("/proc/sys/fs/binfmt_misc")
ENTRY = "qemu-aarch64"
PACKAGE = "qemu-user"
SUITE = "trixie"
CACHE_DIR = LAB_DIR / "cache" / "qemu"
# The "-binfmt-P" name tells qemu that argv[0] is preserved (flag P).
INTERPRETER_NAME = "aarch64-binfmt-P"
CONF_IN_PACKAGE = "usr/share/qemu/binfmt.d/qemu-aarch64.conf"
BINARY_IN_PACKAGE = "usr/bin/qemu-aarch64"
NEEDED_FLAGS = "OCF"


def kernel_has_binfmt_misc(filesystems: str) -> bool:
    """From /proc/filesystems: the kernel has binfmt_misc (built in or loaded)."""
    return any(line.split()[-1:] == ["binfmt_misc"] for line in filesystems.splitlines())


def registration(text: str) -> dict:
    """/proc/sys/fs/binfmt_misc/<entry> as {"enabled", "interpreter", "flags"}."""
    found = {"enabled": False, "interpreter": "", "flags": ""}
    for line in text.splitlines():
        key, _, value = line.partition(" ")
        if line.strip() == "enabled":
            found["enabled"] = True
        elif key == "interpreter":
            found["interpreter"] = value.strip()
        elif key == "flags:":
            found["flags"] = value.strip()
    return found


def problem(entry: dict | None, interpreter: str) -> str | None:
    """Why a registration is not the one the arm64 host needs, or None."""
    if entry is None:
        return f"{ENTRY} is not registered with binfmt_misc"
    if not entry["enabled"]:
        return f"{ENTRY} is registered but disabled"
    if entry["interpreter"] != interpreter:
        return f"{ENTRY} runs {entry['interpreter']}, not {interpreter}"
    missing = [flag for flag in NEEDED_FLAGS if flag not in entry["flags"]]
    if missing:
        return f"{ENTRY} lacks the binfmt_misc flag(s) {''.join(missing)} (has {entry['flags'] or 'none'})"
    return None


def register_line(debian_conf: str, interpreter: str) -> str:
    """Debian's registration line with our interpreter and the C flag:
    ``:name:type:offset:magic:mask:interpreter:flags``."""
    fields = debian_conf.strip().split(":")
    if len(fields) != 8 or fields[1] != ENTRY or fields[2] != "M":
        raise LabError(f"unexpected binfmt line in {PACKAGE}'s {CONF_IN_PACKAGE}: {debian_conf.strip()[:80]!r}")
    flags = fields[7]
    fields[6] = interpreter
    fields[7] = flags + "".join(flag for flag in "CF" if flag not in flags)
    return ":".join(fields)


def _read(path: Path) -> str | None:
    try:
        return path.read_text()
    except OSError:
        return None


def current() -> dict | None:
    text = _read(BINFMT_DIR / ENTRY)
    return None if text is None else registration(text)


def ensure_arm64_emulation() -> str:
    """Make sure arm64 programs run here, in containers too; returns what is
    registered (one line).  Raises LabError with one line when they cannot."""
    if not kernel_has_binfmt_misc(_read(Path("/proc/filesystems")) or ""):
        raise LabError(
            "this kernel has no binfmt_misc (not in /proc/filesystems), so it cannot run arm64 "
            "programs under qemu-user: the arm64 lab host needs a kernel with CONFIG_BINFMT_MISC"
        )
    interpreter, conf = _cached_qemu()
    if problem(current(), str(interpreter)) is None:
        return _described()
    _mount_binfmt_misc()
    if current() is not None:
        _write(BINFMT_DIR / ENTRY, "-1")
    _write(BINFMT_DIR / "register", register_line(conf, str(interpreter)))
    why = problem(current(), str(interpreter))
    if why:
        raise LabError(f"arm64 emulation: {why} after registering it")
    return _described()


def _described() -> str:
    entry = current() or {}
    return f"{ENTRY} -> {entry.get('interpreter')} (flags {entry.get('flags')})"


def _mount_binfmt_misc() -> None:
    if (BINFMT_DIR / "register").exists():
        return
    done = subprocess.run(
        ["mount", "-t", "binfmt_misc", "binfmt_misc", str(BINFMT_DIR)], capture_output=True, text=True
    )
    if done.returncode != 0:
        said = (done.stderr or done.stdout).strip().splitlines() or [f"exit {done.returncode}"]
        raise LabError(f"cannot mount binfmt_misc on {BINFMT_DIR}: {said[-1]} (root is needed)")


def _write(path: Path, text: str) -> None:
    try:
        path.write_text(text)
    except OSError as error:
        raise LabError(f"cannot write {path}: {error.strerror} (root is needed)") from None


def _cached_qemu() -> tuple[Path, str]:
    """(the emulator, Debian's registration line), fetched once."""
    manifest = CACHE_DIR / "manifest.json"
    try:
        known = json.loads(manifest.read_text())
        binary = CACHE_DIR / known["dir"] / INTERPRETER_NAME
        if binary.is_file():
            return binary, known["conf"]
    except (OSError, ValueError, KeyError):
        pass
    from .mirror import MirrorError, TrixieApt

    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    try:
        apt = TrixieApt(CACHE_DIR / "apt")
        apt.apt_get("update")
        version = apt.show([PACKAGE])[PACKAGE]["Version"]
        with tempfile.TemporaryDirectory(dir=CACHE_DIR) as tmp:
            apt.apt_get("download", f"{PACKAGE}={version}", cwd=Path(tmp))
            deb = next(Path(tmp).glob(f"{PACKAGE}_*.deb"))
            subprocess.run(["dpkg-deb", "-x", str(deb), f"{tmp}/x"], check=True, capture_output=True)
            conf = Path(tmp, "x", CONF_IN_PACKAGE).read_text()
            target = CACHE_DIR / version.replace(":", "_")
            target.mkdir(exist_ok=True)
            shutil.copy2(Path(tmp, "x", BINARY_IN_PACKAGE), target / INTERPRETER_NAME)
    except (MirrorError, KeyError, StopIteration, OSError, subprocess.CalledProcessError) as error:
        raise LabError(f"cannot fetch Debian {SUITE}'s {PACKAGE} (the arm64 emulator): {error}") from None
    manifest.write_text(json.dumps({"package": PACKAGE, "version": version, "dir": target.name, "conf": conf}) + "\n")
    return target / INTERPRETER_NAME, conf
