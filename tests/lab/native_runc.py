"""Lab only: a runc the emulated arm64 hosts can start containers with.

Under qemu-user no arm64 runc can start a container: `runc init` clones its
first child with CLONE_PARENT (then the namespaces with CLONE_NEW*), and
qemu-user's clone() accepts only fork-like flags, so it fails with EINVAL
and Docker says "runc create failed: unable to start container process:
waiting for init preliminary setup: read init-p: connection reset by peer".

This machine's kernel is x86_64, so an amd64 runc inside the arm64 host runs
natively (no emulation) and makes the namespaces itself; the container's
arm64 programs then run through binfmt_misc like every other arm64 program
here (the F flag: no emulator inside).  Debian 13's amd64 runc, its dynamic
loader, libc and libseccomp are fetched once into .lab/cache/native-runc/
and copied into each arm64 host at `up`, where the amd64 loader and
libraries live on an amd64 system (the kernel reads the loader's path from
runc; the loader searches /usr/lib/x86_64-linux-gnu), and runc at RUNC.  The
host's own arm64 runc stays as Debian installs it: inventories/lab.yaml
names this one as pi1's Docker default runtime (lab-native-runc), a line no
real arm64 robot has.  dockerd itself, containerd and the shim still run
emulated; Docker's network-namespace hook re-runs dockerd's binary, which
here is qemu, so only host-network containers start (the payload's default).
"""

from __future__ import annotations

import io
import json
import subprocess
import tarfile
import tempfile
import time
from pathlib import Path

from .engine import LAB_DIR, LabError

CACHE_DIR = LAB_DIR / "cache" / "native-runc"
RUNC = "/usr/local/lib/robot-lab/runc"
RUNTIME = "lab-native-runc"
LIBDIR = "usr/lib/x86_64-linux-gnu"
LOADER = "ld-linux-x86-64.so.2"
# (package, path in its deb, path on the host): the files runc needs.
FILES = (
    ("runc", "usr/sbin/runc", RUNC.lstrip("/")),
    ("libc6", f"{LIBDIR}/{LOADER}", f"{LIBDIR}/{LOADER}"),
    ("libc6", f"{LIBDIR}/libc.so.6", f"{LIBDIR}/libc.so.6"),
    ("libseccomp2", f"{LIBDIR}/libseccomp.so.2", f"{LIBDIR}/libseccomp.so.2"),
)
# The loader's path as runc's ELF header names it, as Debian's libc6:amd64 links it.
LINKS = {"lib64": "usr/lib64", f"usr/lib64/{LOADER}": f"../lib/x86_64-linux-gnu/{LOADER}"}


def cached() -> Path:
    """The directory holding FILES' host paths, fetched once."""
    manifest = CACHE_DIR / "manifest.json"
    try:
        directory = CACHE_DIR / json.loads(manifest.read_text())["dir"]
        if all((directory / target).is_file() for _, _, target in FILES):
            return directory
    except (OSError, ValueError, KeyError):
        pass
    from .mirror import MirrorError, TrixieApt

    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    packages = sorted({package for package, _, _ in FILES})
    try:
        apt = TrixieApt(CACHE_DIR / "apt")
        apt.apt_get("update")
        versions = {name: fields["Version"] for name, fields in apt.show(packages).items()}
        directory = CACHE_DIR / f"runc-{versions['runc'].replace(':', '_')}"
        with tempfile.TemporaryDirectory(dir=CACHE_DIR) as tmp:
            apt.apt_get("download", *(f"{name}={versions[name]}" for name in packages), cwd=Path(tmp))
            for package in packages:
                deb = next(Path(tmp).glob(f"{package}_*.deb"))
                subprocess.run(["dpkg-deb", "-x", str(deb), f"{tmp}/{package}"], check=True, capture_output=True)
            for package, source, target in FILES:
                (directory / target).parent.mkdir(parents=True, exist_ok=True)
                # The loader and libraries are symlinks in some releases: copy what they name.
                (directory / target).write_bytes(Path(tmp, package, source).resolve().read_bytes())
    except (MirrorError, KeyError, StopIteration, OSError, subprocess.CalledProcessError) as error:
        raise LabError(f"cannot fetch Debian's amd64 runc for the arm64 hosts: {error}") from None
    manifest.write_text(json.dumps({"versions": versions, "dir": directory.name}) + "\n")
    return directory


def archive(directory: Path) -> bytes:
    """FILES and LINKS as a tar archive to unpack at the host's /."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for _, _, target in FILES:
            data = (directory / target).read_bytes()
            info = tarfile.TarInfo(target)
            info.size, info.mode, info.mtime = len(data), 0o755, int(time.time())
            tar.addfile(info, io.BytesIO(data))
        for link, points_to in LINKS.items():
            info = tarfile.TarInfo(link)
            info.type, info.linkname, info.mtime = tarfile.SYMTYPE, points_to, int(time.time())
            tar.addfile(info)
    return buffer.getvalue()


def install(container) -> None:
    """Copy the amd64 runc into an arm64 host (a running or created container)."""
    if not container.put_archive("/", archive(cached())):
        raise LabError(f"could not copy the native runc into {container.name}")
